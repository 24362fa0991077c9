"""ResultWriter (SPEC 7): exact round trip, XDMF consistency, crash safety, no overwrite.

All data are synthetic: full arrays built from a seeded generator on every rank, each rank
hands the writer an interleaved, shuffled subset of the rows, and the file must hold the
full arrays exactly.
"""

import shutil
import subprocess
import sys
import textwrap
import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import numpy as np
import pytest
from mpi4py import MPI

from parefg.errors import InputError
from parefg.io.output import ResultWriter

# this module is also imported by a child process (CRASHING_RUN), without conftest
REPO = Path(__file__).resolve().parents[2]

N_NODES = 23
N_CONTACT = 7
TIMES = [0.0, 0.125, 0.25]
STEPS = [0, 5, 10]
N_OUTPUTS = len(TIMES)


def synthetic_run(n_steps=N_OUTPUTS):
    """Full (global-order) arrays of a run: coordinates, and node/contact fields per step."""
    rng = np.random.default_rng(7)
    node_coords = rng.random((N_NODES, 2))  # (n_nodes, 2)
    contact_coords = np.column_stack([np.sort(rng.random(N_CONTACT)), np.zeros(N_CONTACT)])
    steps = []
    for _ in range(n_steps):
        node_fields = {
            "displacement": rng.standard_normal((N_NODES, 2)),
            "velocity": rng.standard_normal((N_NODES, 2)),
            "von_mises": rng.random(N_NODES),
        }
        contact_fields = {
            "gap": rng.standard_normal(N_CONTACT),
            "normal_pressure": -rng.random(N_CONTACT),
            "tangential_traction": rng.standard_normal(N_CONTACT),
            "status": rng.integers(0, 3, N_CONTACT).astype(np.int8),
        }
        steps.append((node_fields, contact_fields))
    return node_coords, contact_coords, steps


def owned_rows(comm, n):
    """Interleaved, non-contiguous, shuffled rows of this rank: rank, rank + P, ..."""
    rows = np.arange(comm.rank, n, comm.size)
    return np.random.default_rng(comm.rank).permutation(rows)


@pytest.fixture
def run_dir(comm, tmp_path):
    """One directory shared by all ranks (rank 0's tmp_path)."""
    return Path(comm.bcast(str(tmp_path), root=0)) / "run"


def make_writer(comm, out_dir, node_coords, contact_coords):
    node_rows = owned_rows(comm, N_NODES)
    contact_rows = owned_rows(comm, N_CONTACT)
    metadata = {"params": {"time": {"dt": 0.025, "T": 1.0}, "domain": {"shape": "square"}}}
    metadata.update(version="0.1.0", mpi_ranks=comm.size)
    writer = ResultWriter(
        comm,
        out_dir,
        node_coords=node_coords[node_rows],
        node_rows=node_rows,
        n_nodes=N_NODES,
        contact_coords=contact_coords[contact_rows],
        contact_rows=contact_rows,
        n_contact=N_CONTACT,
        metadata=metadata,
    )
    return writer, node_rows, contact_rows


def write_steps(comm, writer, node_rows, contact_rows, steps, count):
    for k in range(count):
        node_fields, contact_fields = steps[k]
        writer.write_step(
            STEPS[k],
            TIMES[k],
            {name: values[node_rows] for name, values in node_fields.items()},
            {name: values[contact_rows] for name, values in contact_fields.items()},
        )


def write_full_run(comm, out_dir):
    node_coords, contact_coords, steps = synthetic_run()
    writer, node_rows, contact_rows = make_writer(comm, out_dir, node_coords, contact_coords)
    write_steps(comm, writer, node_rows, contact_rows, steps, len(TIMES))
    for k in range(12):
        row = {"time": 0.025 * k, "newton_iterations": 2 + k % 3, "kinetic_energy": 0.5 * k}
        if k >= 4:
            row["extra"] = float(k)
        writer.append_history(row)
    writer.close({"timings": {"total": 1.5, "solve": 1.0}, "n_steps": 12})
    comm.barrier()
    return node_coords, contact_coords, steps


def test_round_trip_is_exact(comm, run_dir):
    node_coords, contact_coords, steps = write_full_run(comm, run_dir)
    with h5py.File(run_dir / "result.h5", "r") as f:
        np.testing.assert_array_equal(f["mesh/coordinates"][()], node_coords)
        np.testing.assert_array_equal(f["contact/coordinates"][()], contact_coords)
        np.testing.assert_array_equal(f["steps/time"][()], TIMES)
        np.testing.assert_array_equal(f["steps/step"][()], STEPS)
        for k, (node_fields, contact_fields) in enumerate(steps):
            for name, values in node_fields.items():
                np.testing.assert_array_equal(f[f"fields/{name}/{k:04d}"][()], values)
            for name, values in contact_fields.items():
                stored = f[f"contact_fields/{name}/{k:04d}"]
                assert stored.dtype == values.dtype
                np.testing.assert_array_equal(stored[()], values)
        assert sorted(f["fields"]) == ["displacement", "velocity", "von_mises"]


def test_history_and_attributes(comm, run_dir):
    write_full_run(comm, run_dir)
    with h5py.File(run_dir / "result.h5", "r") as f:
        history = f["history"]
        assert sorted(history) == ["extra", "kinetic_energy", "newton_iterations", "time"]
        np.testing.assert_array_equal(history["time"][()], 0.025 * np.arange(12))
        np.testing.assert_array_equal(history["newton_iterations"][()], 2 + np.arange(12) % 3)
        # "extra" first appears in row 4: earlier rows read NaN
        assert np.isnan(history["extra"][:4]).all()
        np.testing.assert_array_equal(history["extra"][4:], np.arange(4, 12))
        assert f.attrs["mpi_ranks"] == comm.size
        assert f.attrs["version"] == "0.1.0"
        assert f.attrs["params.time.dt"] == 0.025
        assert f.attrs["params.domain.shape"] == "square"
        assert '"dt": 0.025' in f.attrs["params_json"]
        assert f.attrs["timings.solve"] == 1.0
        assert f.attrs["n_steps"] == 12


def check_xdmf(run_dir, n_steps):
    """Every DataItem names an existing dataset of the declared shape; times match."""
    root = ET.parse(run_dir / "result.xdmf").getroot()
    series = root.find("Domain/Grid")
    assert series.get("CollectionType") == "Temporal"
    snapshots = series.findall("Grid")
    assert len(snapshots) == n_steps
    assert [float(s.find("Time").get("Value")) for s in snapshots] == TIMES[:n_steps]
    items = root.iter("DataItem")
    with h5py.File(run_dir / "result.h5", "r") as f:
        checked = 0
        for item in items:
            file_name, path = item.text.strip().split(":")
            assert file_name == "result.h5"
            shape = tuple(int(n) for n in item.get("Dimensions").split())
            assert f[path].shape == shape, path
            assert int(item.get("Precision")) == f[path].dtype.itemsize
            checked += 1
    # per step: node geometry + 3 node fields, contact geometry + 4 contact fields
    assert checked == n_steps * (1 + 3 + 1 + 4)
    grid_names = {grid.get("Name") for snapshot in snapshots for grid in snapshot.findall("Grid")}
    if n_steps:
        assert grid_names == {"nodes", "contact"}


def test_xdmf_describes_the_h5(comm, run_dir):
    write_full_run(comm, run_dir)
    check_xdmf(run_dir, len(TIMES))


def test_file_readable_mid_run(comm, run_dir):
    """A copy of the files taken after step 2, before close(), is what a crash leaves."""
    node_coords, contact_coords, steps = synthetic_run()
    writer, node_rows, contact_rows = make_writer(comm, run_dir, node_coords, contact_coords)
    try:
        write_steps(comm, writer, node_rows, contact_rows, steps, 2)
        # on 2 ranks the interleaved rows move to their file blocks (collective MPI-IO)
        assert writer.file.driver == ("mpio" if comm.size > 1 else "sec2")
        comm.barrier()
        snapshot = run_dir.parent / "snapshot"
        if comm.rank == 0:
            snapshot.mkdir()
            for name in ("result.h5", "result.xdmf"):
                shutil.copy(run_dir / name, snapshot / name)
        comm.barrier()
        with h5py.File(snapshot / "result.h5", "r") as f:
            np.testing.assert_array_equal(f["steps/time"][()], TIMES[:2])
            np.testing.assert_array_equal(
                f["fields/displacement/0001"][()], steps[1][0]["displacement"]
            )
        check_xdmf(snapshot, 2)
    finally:
        writer.close({})


CRASHING_RUN = """
import os, sys
sys.path.insert(0, {tests!r})
from pathlib import Path
from mpi4py import MPI
import test_output as t
node_coords, contact_coords, steps = t.synthetic_run()
writer, node_rows, contact_rows = t.make_writer(MPI.COMM_SELF, Path({out!r}), node_coords,
                                                contact_coords)
t.write_steps(MPI.COMM_SELF, writer, node_rows, contact_rows, steps, 2)
writer.append_history({{"time": 0.0}})
os._exit(0)  # dies without close(), destructors or atexit handlers
"""


@pytest.mark.serial_only
def test_process_killed_after_two_steps(tmp_path):
    script = CRASHING_RUN.format(
        tests=str(Path(__file__).resolve().parent), out=str(tmp_path / "run")
    )
    subprocess.run([sys.executable, "-c", textwrap.dedent(script)], check=True, timeout=60)
    with h5py.File(tmp_path / "run" / "result.h5", "r") as f:
        np.testing.assert_array_equal(f["steps/step"][()], STEPS[:2])
        assert sorted(f["fields/velocity"]) == ["0000", "0001"]
    check_xdmf(tmp_path / "run", 2)


def test_existing_result_is_input_error(comm, run_dir):
    if comm.rank == 0:
        run_dir.mkdir(parents=True)
        (run_dir / "result.h5").write_bytes(b"precious")
    comm.barrier()
    with pytest.raises(InputError, match="already exists"):
        make_writer(comm, run_dir, *synthetic_run(0)[:2])
    comm.barrier()
    assert (run_dir / "result.h5").read_bytes() == b"precious"


def test_rows_that_do_not_cover_the_points_fail_on_every_rank(comm, run_dir):
    node_coords, contact_coords, _ = synthetic_run(0)
    with pytest.raises(ValueError, match="node rows"):
        ResultWriter(
            comm,
            run_dir,
            node_coords=node_coords[:2],
            node_rows=[0, 1] if comm.rank == 0 else [],
            n_nodes=N_NODES,
            contact_coords=np.zeros((0, 2)),
            contact_rows=[],
            n_contact=0,
            metadata={},
        )


@pytest.mark.serial_only
def test_plot_run_makes_its_pngs(comm, tmp_path):
    run_dir = tmp_path / "run"
    write_full_run(comm, run_dir)
    result = subprocess.run(
        [sys.executable, str(REPO / "scripts" / "plots" / "plot_run.py"), str(run_dir)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    expected = {"displacement.png", "contact_pressure.png", "energy.png", "iterations.png"}
    produced = {path.name for path in (run_dir / "plots").glob("*.png")}
    assert produced == expected
    for name in expected:
        assert (run_dir / "plots" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def bytes_written() -> int:
    """Bytes this process has handed to write calls so far (Linux /proc/self/io wchar)."""
    with open("/proc/self/io") as io:
        return next(int(line.split()[1]) for line in io if line.startswith("wchar"))


@pytest.mark.skipif(not Path("/proc/self/io").exists(), reason="needs Linux /proc/self/io")
def test_cost_of_an_output_does_not_grow_with_the_outputs_before(tmp_path):
    """Bytes written per write_step, outputs 300..350 against 10..60 (XDMF and HDF5).

    Rewriting the XDMF index at every output made the k-th output write O(k) bytes
    (quadratic in all; 500 outputs took 18.8 s); appending keeps it flat.  Each rank
    writes its own file (COMM_SELF): the count is of this process's writes.
    """
    comm, run_dir = MPI.COMM_SELF, tmp_path / "run"
    node_coords, contact_coords, steps = synthetic_run(1)
    writer, node_rows, contact_rows = make_writer(comm, run_dir, node_coords, contact_coords)
    node_fields, contact_fields = steps[0]
    node_fields = {name: values[node_rows] for name, values in node_fields.items()}
    contact_fields = {name: values[contact_rows] for name, values in contact_fields.items()}
    per_output = []
    try:
        for k in range(350):
            before = bytes_written()
            writer.write_step(k, 0.125 * k, node_fields, contact_fields)
            per_output.append(bytes_written() - before)
    finally:
        writer.close({})
    early, late = np.mean(per_output[10:60]), np.mean(per_output[300:350])
    assert late < 1.5 * early, (early, late)
    assert writer.xdmf_bytes_written < 350 * 4096  # one snapshot and the closing tags each
    check_xdmf_steps = ET.parse(run_dir / "result.xdmf").getroot().find("Domain/Grid")
    assert len(check_xdmf_steps.findall("Grid")) == 350
