"""Partition the node cloud once, on rank 0, and send each rank its part as numpy buffers
(SPEC 5).

The recursive coordinate bisection of :func:`~parefg.geometry.partition.partition_cloud`
is deterministic: rank 0 computes it and sends the result, with buffer-based ``Bcast`` and
``Send`` (no pickling of the cloud; only the small headers -- shapes, dtypes, part names
-- are pickled).  Each rank receives the cells it owns, not the whole mesh, and the cell
next to every boundary segment (:class:`~parefg.geometry.cloud.BoundaryCells`, O(boundary)).

Every rank still receives every node (coordinates, spacing, original index) and every
boundary segment: a rank-local node set (owned nodes plus ghosts) is the remaining part
of issue 13.
"""

from __future__ import annotations

import numpy as np
from mpi4py.util.dtlib import from_numpy_dtype

from parefg.geometry.cloud import BoundaryCells, NodeCloud, boundary_cells
from parefg.geometry.partition import Partition, partition_cloud
from parefg.parallel import run_on_root

# what every rank keeps whole: the nodes and the boundary
_SHARED_ARRAYS = ("coords", "spacing", "segments", "segment_part", "original_index")
_CELL_ARRAYS = ("quads", "triangles")  # what each rank keeps of its own
_PARTITION_ARRAYS = ("node_ranges", "segment_owner")
# elements per Bcast or Send: an MPI count is an int, 2^31 - 1 at most (the coordinates of
# 1e9 nodes are 2e9 numbers)
BCAST_CHUNK = 1 << 30


def partition_on_root(comm, cloud: NodeCloud | None) -> tuple[NodeCloud, Partition]:
    """``partition_cloud(cloud, comm.size)`` computed on rank 0, each rank's part sent to
    it.  Collective.

    Returns this rank's cloud: every node and segment, renumbered, with only the cells
    this rank owns (in their order in the whole mesh) and ``segment_cells`` set; and the
    partition without the cells' owners (``quad_owner``, ``triangle_owner`` None).

    ``cloud`` is only read on rank 0 (the other ranks may pass None: the run meshes on
    rank 0 only, :func:`~parefg.geometry.gmsh_mesh.mesh_on_root`).  A bad part count
    raises the InputError of :func:`partition_cloud` on every rank.
    """
    # any failure on rank 0 (a bad part count, memory) ends every rank (run_on_root)
    result = run_on_root(comm, _parts, cloud, comm.size)
    part_names = comm.bcast(None if cloud is None else list(cloud.part_names), root=0)
    renumbered, partition, cells, own = result if result is not None else (None,) * 4
    del result
    shared = _bcast_arrays(
        comm,
        None
        if renumbered is None
        else [getattr(renumbered, a) for a in _SHARED_ARRAYS]
        + [getattr(partition, a) for a in _PARTITION_ARRAYS]
        + [cells.cell, cells.corners],
    )
    del renumbered, partition, cells  # rank 0's whole mesh: each rank keeps its own cells
    own_cells = _scatter_arrays(comm, own)
    n_shared = len(_SHARED_ARRAYS)
    node_ranges, segment_owner, cell, corners = shared[n_shared:]
    rank_cloud = NodeCloud(
        **dict(zip(_SHARED_ARRAYS, shared[:n_shared], strict=True)),
        **dict(zip(_CELL_ARRAYS, own_cells, strict=True)),
        part_names=part_names,
        segment_cells=BoundaryCells(cell=cell, corners=corners),
    )
    partition = Partition(
        n_parts=int(comm.size),
        node_ranges=node_ranges,
        quad_owner=None,
        triangle_owner=None,
        segment_owner=segment_owner,
    )
    return rank_cloud, partition


def _parts(cloud: NodeCloud, n_parts: int) -> tuple:
    """Rank 0's work: the renumbered cloud, its partition, the segments' cells, and each
    part's own cells [[quads, triangles] of part r for r in range(n_parts)]."""
    renumbered, partition = partition_cloud(cloud, n_parts)
    own = [
        [renumbered.quads[partition.quad_owner == part],
         renumbered.triangles[partition.triangle_owner == part]]
        for part in range(n_parts)
    ]  # fmt: skip
    return renumbered, partition, boundary_cells(renumbered), own


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
    for array in arrays:  # contiguous on every rank
        _transfer(array, lambda chunk, dt: comm.Bcast([chunk, dt], root=0))
    return arrays


def _scatter_arrays(comm, per_rank: list[list[np.ndarray]] | None) -> list[np.ndarray]:
    """Rank r gets ``per_rank[r]`` (given on rank 0) with buffer Send (headers pickled).
    Collective."""
    header = None
    if comm.rank == 0:
        assert per_rank is not None
        per_rank = [[np.ascontiguousarray(a) for a in arrays] for arrays in per_rank]
        header = [[(a.shape, a.dtype.str) for a in arrays] for arrays in per_rank]
    mine = comm.scatter(header, root=0)
    if comm.rank == 0:
        assert per_rank is not None
        for rank in range(1, comm.size):
            for array in per_rank[rank]:
                _transfer(array, lambda chunk, dt, r=rank: comm.Send([chunk, dt], dest=r))
        return per_rank[0]
    arrays = [np.empty(shape, dtype=np.dtype(dtype)) for shape, dtype in mine]
    for array in arrays:
        _transfer(array, lambda chunk, dt: comm.Recv([chunk, dt], source=0))
    return arrays


def _transfer(array: np.ndarray, move) -> None:
    """``move(chunk, datatype)`` for each chunk of at most BCAST_CHUNK elements of a
    contiguous array (MPI counts are 32-bit ints)."""
    flat = array.reshape(-1)  # a view: the array is contiguous
    datatype = from_numpy_dtype(array.dtype)  # any byte-order flag of the buffer is moot
    for start in range(0, flat.size, BCAST_CHUNK):
        move(flat[start : start + BCAST_CHUNK], datatype)
