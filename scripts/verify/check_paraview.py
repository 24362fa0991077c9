"""Open a run's result.xdmf with ParaView's own reader; compare field ranges with h5py.

Run with ParaView's Python (Debian: `apt-get install paraview python3-paraview`):

    pvbatch scripts/verify/check_paraview.py RUNDIR

For the last output time, every point array of every grid ParaView reads ("nodes",
"contact") is compared component-wise (min and max) with the same dataset read by h5py;
prints a table and exits 1 on any mismatch beyond 1e-12 relative (or a missing array).
"""

import sys
from pathlib import Path

import h5py
import numpy as np
from paraview import servermanager
from paraview.simple import OpenDataFile
from vtk.numpy_interface import dataset_adapter as dsa

GROUPS = {"nodes": "fields", "contact": "contact_fields"}


def paraview_arrays(xdmf: Path):
    """{(n_points, array): numpy values} at the last time step, as ParaView reads them.

    The reader does not name the leaf blocks; the grids are told apart by point count.
    """
    reader = OpenDataFile(str(xdmf))
    last_time = reader.TimestepValues[-1]
    reader.UpdatePipeline(last_time)
    data = dsa.WrapDataObject(servermanager.Fetch(reader))
    arrays = {}
    iterator = data.VTKObject.NewIterator()
    iterator.InitTraversal()
    while not iterator.IsDoneWithTraversal():
        block = dsa.WrapDataObject(iterator.GetCurrentDataObject())
        for key in block.PointData.keys():
            arrays[(block.GetNumberOfPoints(), key)] = np.asarray(block.PointData[key])
        iterator.GoToNextItem()
    return last_time, arrays


def main(run_dir: Path) -> int:
    last_time, arrays = paraview_arrays(run_dir / "result.xdmf")
    failures = 0
    print(f"t = {last_time}: {'grid':<8} {'array':<20} {'ParaView':>30} {'h5py':>30}")
    with h5py.File(run_dir / "result.h5", "r") as handle:
        k = f"{len(handle['steps/time']) - 1:04d}"
        for grid, group in GROUPS.items():
            if group not in handle:
                continue
            for field in handle[group]:
                expected = handle[f"{group}/{field}/{k}"][...].astype(float)
                got = arrays.get((expected.shape[0], field))
                if got is None:
                    print(f"  MISSING in ParaView: {grid}/{field}")
                    failures += 1
                    continue
                got = got.astype(float)[:, : expected.shape[1]] if expected.ndim == 2 else got
                ranges = [(np.min(a, axis=0), np.max(a, axis=0)) for a in (got, expected)]
                scale = max(np.abs(expected).max(), 1e-300)
                ok = all(
                    np.allclose(a, b, rtol=0, atol=1e-12 * scale)
                    for a, b in zip(ranges[0], ranges[1], strict=True)
                )
                failures += not ok
                fmt = lambda r: f"{np.min(r[0]):.6g}..{np.max(r[1]):.6g}"  # noqa: E731
                print(
                    f"  {'ok  ' if ok else 'FAIL'} {grid:<8} {field:<20} {fmt(ranges[0]):>30} "
                    f"{fmt(ranges[1]):>30}"
                )
    print("all ranges match" if not failures else f"{failures} mismatch(es)")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1])))
