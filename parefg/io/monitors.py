"""Observers of the time loop that are not results: progress lines and stop requests.

:class:`Progress` prints on rank 0 from rank 0's clock only (no collective, no decision
another rank depends on).  :class:`StopRequest` turns SIGINT / SIGTERM into a flag that
the ranks agree on after each step, so that every rank stops after the same step and
closes the output collectively.
"""

from __future__ import annotations

import signal
import threading
import time
from typing import Any

from mpi4py import MPI

PROGRESS_INTERVAL = 2.0  # seconds of wall time between progress lines, at most
PROGRESS_MARKS = 10  # and a line at every 1/PROGRESS_MARKS of the run
# Ctrl-C; and what mpirun sends every rank when it gets Ctrl-C (Open MPI 4 does not
# forward SIGINT: it sends SIGTERM, then SIGKILL after odls_base_sigkill_timeout)
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Progress:
    """Rank-0 progress lines: at every 10 % of the run and at least every ~2 s of wall time.

    Parameters
    ----------
    comm : mpi4py.MPI.Comm
        Only rank 0 prints; no call is collective.
    n_steps : int
        Last step of the run.
    quiet : bool
        Print nothing.
    first : int
        First step of this run (a restart starts after its checkpoint): the ETA is taken
        from the steps done here.
    """

    def __init__(self, comm, n_steps: int, quiet: bool, first: int = 1):
        self.show = comm.rank == 0 and not quiet
        self.n_steps, self.first = n_steps, first
        self.start = self.last = time.perf_counter()
        self.every = max(1, n_steps // PROGRESS_MARKS)

    def after_step(self, sim, step) -> None:
        """As an observer of the time loop (not collective)."""
        self.update(step.n, step.row["time"], step.row["newton_iterations"])

    def update(self, n: int, t: float, newton: int) -> None:
        """After step ``n`` (time ``t``, ``newton`` iterations): print if a line is due."""
        if not self.show:
            return
        now = time.perf_counter()
        mark = n % self.every == 0 or n == self.n_steps
        if not mark and now - self.last < PROGRESS_INTERVAL:
            return
        self.last = now
        elapsed = now - self.start
        eta = elapsed / max(1, n - self.first + 1) * (self.n_steps - n)
        print(
            f"  step {n:>5}/{self.n_steps}  t = {t:<10.4g} newton {newton:>2}  "
            f"elapsed {elapsed:7.2f} s  eta {eta:7.2f} s",
            flush=True,
        )


class StopRequest:
    """SIGINT / SIGTERM request a stop; the ranks agree on it after each step.

    Use as a context manager around the run: inside it the signals only set a flag (and
    put the previous handlers back, so a second Ctrl-C ends the process the usual way).
    Signal handlers exist only in the main thread; elsewhere nothing is installed.
    """

    def __init__(self, comm):
        self.comm = comm
        self.signal = 0  # number of the signal received on this rank, 0 if none
        self._previous: dict[int, Any] = {}  # signal number -> handler before ours

    def __enter__(self) -> StopRequest:
        if threading.current_thread() is threading.main_thread():
            for number in STOP_SIGNALS:
                self._previous[number] = signal.signal(number, self._received)
        return self

    def __exit__(self, *exc) -> None:
        self._restore()

    def reclaim(self) -> None:
        """Put the handlers back after code that replaced them (gmsh's import sets SIGINT to
        the default and its finalize restores the handler of its import time)."""
        if self._previous and not self.signal:
            for number in self._previous:
                signal.signal(number, self._received)

    def _received(self, number, frame) -> None:
        self.signal = number
        self._restore()

    def _restore(self) -> None:
        for number, handler in self._previous.items():
            signal.signal(number, handler)
        self._previous.clear()

    def agreed(self) -> int:
        """The signal any rank received (the largest number), 0 if none.  Collective.

        One allreduce of an int per call on more than one rank; nothing on one rank.
        """
        if self.comm.size == 1:
            return self.signal
        return self.comm.allreduce(self.signal, op=MPI.MAX)

    @staticmethod
    def name(number: int) -> str:
        return signal.Signals(number).name
