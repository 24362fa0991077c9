"""The parallel layer: collectives, failures decided together, PETSc construction helpers.

Every function takes the communicator first and says whether it is collective.  Two rules
of SPEC 6 live here so that no other module writes them by hand:

* a failure found on one rank is raised on every rank (:func:`raise_everywhere`,
  :func:`call_on_root`), decided through one collective before the next one, so no rank
  waits in a collective that another rank skipped;
* a rank that leaves a block early waits a bounded time for the others and aborts the job
  otherwise (:func:`wait_for_all`), so a run never hangs under mpirun.

The sparse helpers move this rank's contributions to the rows their owners hold
(:func:`owned_rows`) and build PETSc matrices with exact preallocation from them.  Rank r
owns the contiguous rows ``row_ranges[r]:row_ranges[r + 1]``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI
from petsc4py import PETSc

from parefg.errors import InputError

T = TypeVar("T")
POLL_SECONDS = 0.001  # how often a waiting rank tests its non-blocking barrier


# -- failures decided together ---------------------------------------------------------
def raise_everywhere(comm, error: Exception | None, *, root: int | None = None) -> None:
    """Raise on every rank the failure one rank found; return if there is none.  Collective.

    Parameters
    ----------
    error : Exception or None
        What this rank found (None: nothing).  Its class must be constructible from its
        message alone (``InputError(message)``); only the class and message travel.
    root : int, optional
        None: every rank's ``error`` counts (one allgather) and the first failing rank's
        is raised.  A rank number: only that rank's counts (one bcast), for verdicts that
        one rank reaches for all (files it read, round-off it judged).

    A failing rank raises its own exception object (keeping its traceback); the others
    raise a new one of the same class and message.
    """
    local = None if error is None else (type(error), str(error))
    if root is None:
        found = next((f for f in comm.allgather(local) if f is not None), None)
    else:
        found = comm.bcast(local, root=root)
    if found is None:
        return
    kind, message = found
    if error is not None and type(error) is kind and str(error) == message:
        raise error
    raise kind(message)


def raise_unless_everywhere(comm, ok: bool, error: Exception) -> None:
    """Raise ``error`` on every rank unless ``ok`` holds on every rank.  Collective.

    One allreduce; for a check each rank makes on its own data.
    """
    if not comm.allreduce(bool(ok), op=MPI.LAND):
        raise error


def same_everywhere(comm, value) -> bool:
    """Whether ``value`` (compared with ==) is the same on every rank.  Collective."""
    values = comm.allgather(value)
    return all(other == values[0] for other in values)


def run_on_root(
    comm,
    task: Callable[..., T],
    *args,
    expected: tuple[type[Exception], ...] = (InputError,),
    root: int = 0,
) -> T | None:
    """Run ``task(*args)`` on ``root`` only; its result there, None on the other ranks.

    Collective.  For work only one rank may do (create a directory, read a file, mesh):
    an ``expected`` exception raised by the task is raised on every rank
    (:func:`raise_everywhere`); any other exception is a defect, raised as it is on
    ``root`` and as RuntimeError naming it on the other ranks, so every rank ends.
    """
    result, defect = None, None
    failure: tuple[Any, str] | None = None  # (exception class or "internal", message)
    if comm.rank == root:
        try:
            result = task(*args)
        except expected as error:
            failure = (type(error), str(error))
        except Exception as error:  # a defect: still end every rank, not only the root
            failure, defect = ("internal", f"{type(error).__name__}: {error}"), error
    failure = comm.bcast(failure, root=root)
    if failure is None:
        return result
    kind, message = failure
    if defect is not None:
        raise defect
    if kind == "internal":
        raise RuntimeError(f"{task.__name__} failed on rank {root}: {message}")
    raise kind(message)


def call_on_root(comm, task: Callable[..., T], *args, **options) -> T:
    """:func:`run_on_root` (the same arguments), its result broadcast (pickled) to every
    rank.  Collective."""
    return comm.bcast(run_on_root(comm, task, *args, **options), root=options.get("root", 0))


def wait_for_all(comm, patience: float | None, abort_code: int) -> None:
    """Wait until every rank arrives; abort the job after ``patience`` seconds.  Collective.

    A non-blocking barrier, tested every POLL_SECONDS: a rank that failed waits for the
    others to leave the block they were in, and if they are stuck in a collective it left
    (``patience`` None: wait as long as it takes) ``comm.Abort(abort_code)`` ends the job.
    """
    if comm.size == 1:
        return
    request = comm.Ibarrier()
    deadline = None if patience is None else time.monotonic() + patience
    while not request.Test():
        if deadline is not None and time.monotonic() > deadline:
            comm.Abort(abort_code)
        time.sleep(POLL_SECONDS)


# -- rows of distributed arrays ---------------------------------------------------------
def alltoallv(comm, send: np.ndarray, send_counts: np.ndarray) -> np.ndarray:
    """Exchange a 1-D array in blocks: block r of ``send`` goes to rank r.  Collective."""
    recv_counts = np.empty(comm.size, dtype=np.int64)
    comm.Alltoall(send_counts.astype(np.int64), recv_counts)
    recv = np.empty(int(recv_counts.sum()), dtype=send.dtype)
    send_displs = np.concatenate([[0], np.cumsum(send_counts)[:-1]])
    recv_displs = np.concatenate([[0], np.cumsum(recv_counts)[:-1]])
    mpi_type = MPI._typedict[send.dtype.char]
    comm.Alltoallv(
        [send, (send_counts, send_displs), mpi_type], [recv, (recv_counts, recv_displs), mpi_type]
    )
    return recv


def owned_rows(
    comm,
    local: sp.spmatrix,
    row_ranges: np.ndarray,
    ids: np.ndarray | None = None,
    n_cols: int | None = None,
) -> sp.csr_matrix:
    """Sum every rank's contributions into the rows each rank owns.  Collective.

    Parameters
    ----------
    local : (n_rows, n_cols) sparse matrix holding this rank's contributions (rows
        anywhere), with global row and column indices, or with positions in ``ids``.
    row_ranges : (comm.size + 1,) rank r owns rows row_ranges[r]:row_ranges[r + 1].
    ids : (n_rows,) int, optional
        The global index of each row and column of a square ``local`` numbered by the
        rows it touches (ascending): a rank holding only some of the nodes
        (:mod:`parefg.discretization.ghosts`), or a contact Jacobian's few rows, never
        makes a matrix with a row per global index.  None: ``local`` has global indices.
    n_cols : int, optional
        The global column count with ``ids`` (default: ``local``'s).

    Returns
    -------
    (n_owned_rows, n_cols) canonical CSR matrix of the summed owned rows (sorted columns,
    duplicates added), explicit zeros kept (they carry sparsity patterns reserved for
    later values), with global columns.
    """
    local = sp.csr_matrix(local)
    local.sum_duplicates()  # canonical CSR: sorted columns, duplicates added, zeros kept
    if ids is not None:
        ids = np.asarray(ids, dtype=np.int64)
        local = global_columns(local, ids, local.shape[1] if n_cols is None else n_cols)
        local.has_canonical_format = True  # ascending ids: the columns stay sorted
    rank = comm.rank
    start, stop = int(row_ranges[rank]), int(row_ranges[rank + 1])
    if comm.size == 1 and ids is None:
        return local
    row_ids = np.arange(local.shape[0]) if ids is None else ids
    # CSR rows come grouped by owner: rank r's entries are one contiguous slice.  This
    # rank's own slice stays where it is; only the others' (the rows of nodes across the
    # partition's interface) travel, and are merged into the few rows they touch.
    positions = np.searchsorted(row_ids, row_ranges)  # (comm.size + 1,) first row of each
    first, last = int(positions[rank]), int(positions[rank + 1])
    bounds = local.indptr[positions]  # (comm.size + 1,)
    counts = np.diff(bounds)
    counts[rank] = 0
    low, high = int(bounds[rank]), int(bounds[rank + 1])
    row_counts = np.diff(local.indptr)
    send_rows = np.concatenate(
        [
            np.repeat(row_ids[:first], row_counts[:first]),
            np.repeat(row_ids[last:], row_counts[last:]),
        ]
    )
    send_cols = np.concatenate([local.indices[:low], local.indices[high:]])
    send_data = np.concatenate([local.data[:low], local.data[high:]])
    rows = alltoallv(comm, send_rows.astype(np.int64), counts) - start
    cols = alltoallv(comm, send_cols.astype(np.int64), counts)
    data = alltoallv(comm, send_data.astype(np.float64), counts)
    own_indptr = local.indptr[first : last + 1] - low
    if ids is not None:  # the own rows held (a contact Jacobian's: some), spread out
        counts_own = np.zeros(stop - start, dtype=np.int64)
        counts_own[row_ids[first:last] - start] = np.diff(own_indptr)
        own_indptr = np.zeros(stop - start + 1, dtype=np.int64)
        np.cumsum(counts_own, out=own_indptr[1:])
    own = sp.csr_matrix(
        (local.data[low:high], local.indices[low:high], own_indptr),
        shape=(stop - start, local.shape[1]),
    )
    own.has_canonical_format = True  # a row slice of a canonical matrix
    if len(rows) == 0:
        return own
    return _merge_rows(own, rows, cols, data)


def add_entries(own: sp.csr_matrix, rows, cols, data) -> sp.csr_matrix:
    """``own`` (canonical CSR) plus the COO entries (rows, cols, data), explicit zeros kept:
    only the rows they touch are summed again (see :func:`_merge_rows`).  Local."""
    if len(rows) == 0:
        return own
    return _merge_rows(own, np.asarray(rows), np.asarray(cols), np.asarray(data))


def global_columns(local: sp.spmatrix, ids: np.ndarray, n_cols: int) -> sp.csr_matrix:
    """``local`` with column j renamed ``ids[j]`` (ascending: sorted columns stay sorted),
    of ``n_cols`` columns.  Not collective."""
    local = sp.csr_matrix(local)
    return sp.csr_matrix(
        (local.data, ids[local.indices], local.indptr), shape=(local.shape[0], int(n_cols))
    )


def _merge_rows(own: sp.csr_matrix, rows, cols, data) -> sp.csr_matrix:
    """``own`` (canonical CSR) plus the entries (rows, cols, data), explicit zeros kept.

    Only the rows the entries touch are re-summed (through COO, which adds duplicates and
    keeps zeros); the runs of untouched rows between them are copied as slices, so the
    cost is one pass over ``own`` plus the touched rows (the partition's interface), not
    several full-length index arrays.
    """
    touched = np.unique(rows)
    compact = np.searchsorted(touched, rows)
    # own entries of the touched rows, then the received ones, as one small COO
    first, last = own.indptr[touched], own.indptr[touched + 1]
    taken = np.repeat(np.arange(len(touched)), last - first)
    offsets = np.arange(len(taken)) - np.repeat(
        np.cumsum(last - first) - (last - first), last - first
    )
    entry = first[taken] + offsets
    small = sp.coo_matrix(
        (
            np.concatenate([own.data[entry], data]),
            (np.concatenate([taken, compact]), np.concatenate([own.indices[entry], cols])),
        ),
        shape=(len(touched), own.shape[1]),
    ).tocsr()  # sums duplicates, sorts columns, keeps explicit zeros
    new_counts = np.diff(own.indptr)
    new_counts[touched] = np.diff(small.indptr)
    indptr = np.zeros(len(new_counts) + 1, dtype=np.int64)
    np.cumsum(new_counts, out=indptr[1:])
    # in row order: the run of untouched rows before each touched row (one slice of own),
    # then that row's summed entries; the run after the last touched row closes the list
    run_starts = own.indptr[np.concatenate([[0], touched + 1])]
    run_ends = own.indptr[np.append(touched, len(new_counts))]
    index_parts, value_parts = [], []
    for k in range(len(touched)):
        run = slice(run_starts[k], run_ends[k])
        summed = slice(small.indptr[k], small.indptr[k + 1])
        index_parts += [own.indices[run], small.indices[summed]]
        value_parts += [own.data[run], small.data[summed]]
    index_parts.append(own.indices[run_starts[-1] : run_ends[-1]])
    value_parts.append(own.data[run_starts[-1] : run_ends[-1]])
    indices = np.concatenate(index_parts).astype(own.indices.dtype, copy=False)
    values = np.concatenate(value_parts).astype(own.data.dtype, copy=False)
    merged = sp.csr_matrix((values, indices, indptr), shape=own.shape)
    merged.has_canonical_format = True
    return merged


# -- PETSc construction -----------------------------------------------------------------
def _csr_arrays(matrix: sp.csr_matrix):
    matrix.sort_indices()
    return (
        matrix.indptr.astype(PETSc.IntType),
        matrix.indices.astype(PETSc.IntType),
        matrix.data.astype(PETSc.ScalarType),
    )


def petsc_matrix(comm, owned: sp.csr_matrix, n_cols_local: int, n_cols: int, block_size: int = 1):
    """PETSc AIJ matrix from this rank's owned rows (global columns).  Collective.

    The CSR arrays give the exact preallocation; inserting outside the pattern later is
    an error (no mallocs during value updates within the same pattern).
    """
    n_rows_local = owned.shape[0]
    matrix = PETSc.Mat().createAIJ(
        size=((n_rows_local, PETSc.DETERMINE), (n_cols_local, n_cols)),
        csr=_csr_arrays(owned),
        bsize=block_size if block_size > 1 else None,
        comm=comm,
    )
    matrix.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
    matrix.assemble()
    return matrix


def add_owned_rows(matrix, owned: sp.csr_matrix) -> None:
    """Add owned-row values (a pattern subset of ``matrix``) into a PETSc matrix.  Collective."""
    matrix.setValuesCSR(*_csr_arrays(owned), addv=PETSc.InsertMode.ADD_VALUES)
    matrix.assemble()


@contextmanager
def default_options(prefix: str, defaults: dict[str, Any]) -> Iterator[list[str]]:
    """Offer ``defaults`` to the next setFromOptions of an object with options ``prefix``.

    Each default (name without '-' and without the prefix) is put into the global options
    database as ``prefix + name`` only if nobody set that option (the command line and
    the scene's [solver] table win), and exactly those entries are deleted on exit,
    whatever happens: the database is as before afterwards.  For settings petsc4py cannot
    make on the object itself (petsc4py 3.18 has no SNES.getLineSearch).  Yields the
    names inserted.  Not collective (every rank does the same).
    """
    options = PETSc.Options()
    inserted = [prefix + name for name in defaults if not options.hasName(prefix + name)]
    for name in inserted:
        options.setValue(name, defaults[name.removeprefix(prefix)])
    try:
        yield inserted
    finally:
        for name in inserted:
            options.delValue(name)


def set_from_options(obj, prefix: str, defaults: dict[str, Any] | None = None) -> None:
    """Give a PETSc object its options prefix and read its options once.  Collective.

    ``defaults`` (see :func:`default_options`) apply only where no option was given, and
    only while this object reads them.  An empty ``prefix`` reads the unprefixed options
    (``-ksp_type``, ``-snes_rtol``): the step solver's, as the README documents them.
    """
    obj.setOptionsPrefix(prefix or None)
    with default_options(prefix, defaults or {}):
        obj.setFromOptions()
