"""Partition the node cloud once, on rank 0, and send the result as numpy buffers (SPEC 5).

First step of issue 13: the recursive coordinate bisection of
:func:`~parefg.geometry.partition.partition_cloud` is deterministic, so computing it on
rank 0 and broadcasting it gives every rank the same result the ranks used to compute
each on their own.  The arrays travel with buffer-based ``Bcast`` (no pickling of the
cloud); only the small header (shapes, dtypes, part names) is pickled.

Every rank still receives the whole renumbered cloud: the rank-local cloud (owned nodes
plus ghosts) is the remaining part of issue 13.
"""

from __future__ import annotations

import numpy as np
from mpi4py.util.dtlib import from_numpy_dtype

from parefg.geometry.cloud import NodeCloud
from parefg.geometry.partition import Partition, partition_cloud
from parefg.parallel import run_on_root

_CLOUD_ARRAYS = (
    "coords", "spacing", "quads", "triangles", "segments", "segment_part", "original_index",
)  # fmt: skip
_PARTITION_ARRAYS = ("node_ranges", "quad_owner", "triangle_owner", "segment_owner")
# elements per Bcast: an MPI count is an int, 2^31 - 1 at most (the coordinates of 1e9 nodes
# are 2e9 numbers)
BCAST_CHUNK = 1 << 30


def partition_on_root(comm, cloud: NodeCloud | None) -> tuple[NodeCloud, Partition]:
    """``partition_cloud(cloud, comm.size)`` computed on rank 0 only, broadcast.  Collective.

    ``cloud`` is only read on rank 0 (the other ranks may pass None: the run meshes on
    rank 0 only, :func:`~parefg.geometry.gmsh_mesh.mesh_on_root`).  A bad part count
    raises the InputError of :func:`partition_cloud` on every rank.
    """
    # any failure on rank 0 (a bad part count, memory) ends every rank (run_on_root)
    result = run_on_root(comm, partition_cloud, cloud, comm.size)
    part_names = comm.bcast(None if cloud is None else list(cloud.part_names), root=0)
    renumbered, partition = result if result is not None else (None, None)
    cloud_arrays = _bcast_arrays(
        comm, None if renumbered is None else [getattr(renumbered, a) for a in _CLOUD_ARRAYS]
    )
    part_arrays = _bcast_arrays(
        comm, None if partition is None else [getattr(partition, a) for a in _PARTITION_ARRAYS]
    )
    if comm.rank != 0:
        renumbered = NodeCloud(
            **dict(zip(_CLOUD_ARRAYS, cloud_arrays, strict=True)),
            part_names=part_names,
        )
        partition = Partition(
            n_parts=int(comm.size), **dict(zip(_PARTITION_ARRAYS, part_arrays, strict=True))
        )
    assert renumbered is not None and partition is not None
    return renumbered, partition


def _bcast_arrays(comm, arrays: list[np.ndarray] | None) -> list[np.ndarray]:
    """Broadcast numpy arrays from rank 0 with buffer Bcast (header pickled).  Collective."""
    header = None
    if comm.rank == 0:
        assert arrays is not None
        arrays = [np.ascontiguousarray(a) for a in arrays]
        header = [(a.shape, a.dtype.str) for a in arrays]
    header = comm.bcast(header, root=0)
    if comm.rank != 0:
        arrays = [np.empty(shape, dtype=np.dtype(dtype)) for shape, dtype in header]
    assert arrays is not None
    for array in arrays:
        flat = array.reshape(-1)  # a view: arrays are contiguous on every rank
        datatype = from_numpy_dtype(array.dtype)  # any byte-order flag of the buffer is moot
        for start in range(0, flat.size, BCAST_CHUNK):  # MPI counts are 32-bit ints
            comm.Bcast([flat[start : start + BCAST_CHUNK], datatype], root=0)
    return arrays
