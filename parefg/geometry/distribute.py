"""Partition the node cloud once, on rank 0, and send each rank its part as numpy buffers
(SPEC 5).

The recursive coordinate bisection of :func:`~parefg.geometry.partition.partition_cloud`
is deterministic: rank 0 computes it and sends the result, with buffer-based ``Bcast`` and
``Send`` (no pickling of the cloud; only the small headers -- shapes, dtypes, part names
-- are pickled).  Each rank receives the cells it owns, not the whole mesh, and the nodes
those cells, its own nodes and the boundary use; every rank receives the boundary
(segments and the cell next to each, :class:`~parefg.geometry.cloud.BoundaryCells`):
O(N / p + boundary) per rank.  The ghost nodes whose supports reach a rank's part come
from their owners afterwards (:mod:`parefg.discretization.ghosts`).
"""

from __future__ import annotations

import numpy as np
from mpi4py.util.dtlib import from_numpy_dtype

from parefg.geometry.cloud import BoundaryCells, NodeCloud, boundary_cells
from parefg.geometry.partition import Partition, partition_cloud
from parefg.parallel import run_on_root

# what every rank keeps whole: the boundary, the partition's ranges
_SHARED_ARRAYS = ("segments", "segment_part")
_PARTITION_ARRAYS = ("node_ranges", "segment_owner")
# what each rank keeps of its own: its nodes' numbers and data, its cells
_HELD_ARRAYS = ("node_ids", "coords", "spacing", "original_index", "quads", "triangles")
# elements per Bcast or Send: an MPI count is an int, 2^31 - 1 at most (the coordinates of
# 1e9 nodes are 2e9 numbers)
BCAST_CHUNK = 1 << 30


def partition_on_root(comm, cloud: NodeCloud | None) -> tuple[NodeCloud, Partition]:
    """``partition_cloud(cloud, comm.size)`` computed on rank 0, each rank's part sent to
    it.  Collective.

    Returns this rank's cloud and the partition without the cells' owners
    (``quad_owner``, ``triangle_owner`` None).  The cloud holds the nodes of this rank's
    part, of its cells (in their order in the whole mesh) and of the boundary, with
    ``node_ids`` their global numbers (None on one rank: every node), every segment and
    ``segment_cells``; cells, segments and segment cells refer to the nodes held.

    ``cloud`` is only read on rank 0 (the other ranks may pass None: the run meshes on
    rank 0 only, :func:`~parefg.geometry.gmsh_mesh.mesh_on_root`).  A bad part count
    raises the InputError of :func:`partition_cloud` on every rank.
    """
    # any failure on rank 0 (a bad part count, memory) ends every rank (run_on_root)
    result = run_on_root(comm, _parts, cloud, comm.size)
    part_names = comm.bcast(None if cloud is None else list(cloud.part_names), root=0)
    renumbered, partition, cells, held = result if result is not None else (None,) * 4
    del result
    shared = _bcast_arrays(
        comm,
        None
        if renumbered is None
        else [getattr(renumbered, a) for a in _SHARED_ARRAYS]
        + [getattr(partition, a) for a in _PARTITION_ARRAYS]
        + [cells.cell, cells.corners],
    )
    del renumbered, partition, cells  # rank 0's whole mesh: each rank keeps its part
    mine = dict(zip(_HELD_ARRAYS, _scatter_arrays(comm, held), strict=True))
    del held
    segments, segment_part, node_ranges, segment_owner, cell, corners = shared
    node_ids = mine.pop("node_ids")
    complete = len(node_ids) == node_ranges[-1]  # every node (one rank): numbered as held
    held_ids = None if complete else node_ids
    rank_cloud = NodeCloud(
        coords=mine["coords"],
        spacing=mine["spacing"],
        original_index=mine["original_index"],
        quads=_held_positions(held_ids, mine["quads"]),
        triangles=_held_positions(held_ids, mine["triangles"]),
        segments=_held_positions(held_ids, segments),
        segment_part=segment_part,
        part_names=part_names,
        segment_cells=BoundaryCells(cell=cell, corners=_held_positions(held_ids, corners)),
        node_ids=held_ids,
    )
    partition = Partition(
        n_parts=int(comm.size),
        node_ranges=node_ranges,
        quad_owner=None,
        triangle_owner=None,
        segment_owner=segment_owner,
    )
    return rank_cloud, partition


def _held_positions(node_ids: np.ndarray | None, nodes: np.ndarray) -> np.ndarray:
    """``nodes`` (global numbers, -1 kept as -1) as positions in the ascending
    ``node_ids`` that hold them all (None: the numbers are the positions).  Not
    collective."""
    if node_ids is None:
        return nodes
    return np.where(nodes >= 0, np.searchsorted(node_ids, nodes), -1).astype(np.int64)


def _parts(cloud: NodeCloud, n_parts: int) -> tuple:
    """Rank 0's work: the renumbered cloud, its partition, the segments' cells, and each
    part's held arrays (_HELD_ARRAYS, in that order, for part r at index r).

    Part r holds its own nodes, its cells' nodes and the boundary's (the segments' ends
    and the corners of their cells); one part holds every node as it is (no copies).
    """
    renumbered, partition = partition_cloud(cloud, n_parts)
    segment_cells = boundary_cells(renumbered)
    if n_parts == 1:
        every = np.arange(renumbered.n_nodes)
        held = [[every, *(getattr(renumbered, a) for a in _HELD_ARRAYS[1:])]]
        return renumbered, partition, segment_cells, held
    corners = segment_cells.corners
    boundary = np.union1d(renumbered.segments.ravel(), corners[corners >= 0])
    held = []
    for part in range(n_parts):
        quads = renumbered.quads[partition.quad_owner == part]
        triangles = renumbered.triangles[partition.triangle_owner == part]
        start, stop = partition.node_ranges[part], partition.node_ranges[part + 1]
        ids = np.union1d(
            np.arange(start, stop),
            np.union1d(np.union1d(quads.ravel(), triangles.ravel()), boundary),
        ).astype(np.int64)
        data = [renumbered.coords[ids], renumbered.spacing[ids], renumbered.original_index[ids]]
        held.append([ids, *data, quads, triangles])
    return renumbered, partition, segment_cells, held


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
