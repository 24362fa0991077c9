"""Per-phase wall times of a run, also visible as PETSc events in ``-log_view``.

Every phase of the pipeline (mesh, mls, assembly, solve, output) is timed with
:func:`phase`, which adds the elapsed time to a dict and brackets the work in a
PETSc.Log event named ``parefg.<phase>``.  The factorization time is PETSc's own: the
sum of its symbolic and numeric factorization events, which PETSc records whenever
logging is on (:func:`start_logging`).
"""

from __future__ import annotations

import resource
import time
from contextlib import contextmanager
from pathlib import Path

from petsc4py import PETSc

FACTORIZATION_EVENTS = ("MatCholFctrSym", "MatCholFctrNum", "MatLUFactorSym", "MatLUFactorNum")
_events: dict[str, PETSc.Log.Event] = {}


def start_logging() -> None:
    """Turn on PETSc's default logging (idempotent; -log_view turns it on as well)."""
    PETSc.Log.begin()


@contextmanager
def phase(timings: dict[str, float], name: str):
    """Time the block into ``timings[name]`` (accumulating) and log it as a PETSc event."""
    if name not in _events:
        _events[name] = PETSc.Log.Event(f"parefg.{name}")
    event = _events[name]
    event.begin()
    tic = time.perf_counter()
    try:
        yield
    finally:
        timings[name] = timings.get(name, 0.0) + time.perf_counter() - tic
        event.end()


def factorization_stats() -> tuple[float, int]:
    """(seconds, count) of numeric factorizations so far on this rank, from PETSc's log."""
    seconds, count = 0.0, 0
    for name in FACTORIZATION_EVENTS:
        info = PETSc.Log.Event(name).getPerfInfo()
        seconds += info["time"]
        count += info["count"] if name.endswith("Num") else 0
    return seconds, count


def peak_rss_kib() -> int:
    """Peak resident memory of this process in KiB: Linux's VmHWM, else ru_maxrss.

    Not ru_maxrss where /proc has VmHWM: at exec Linux carries the parent's peak into
    ru_maxrss, so a run started from a large process (a test worker, a driver script)
    reported the parent's memory as its own.  Not collective.
    """
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux
