"""The time loop: advance a simulation step by step and tell its observers (SPEC 4, 7).

The loop owns only what every rank must decide together: whether to stop after a step
(a Ctrl-C on any rank, agreed through :class:`~parefg.io.monitors.StopRequest`).  All the
rest -- results, checkpoints, progress lines, a benchmark's callback -- are observers, in
the spirit of PyFR's plugins: objects with ``after_step(sim, step)``, called in order on
every rank after each step, with the same :class:`Step` on every rank.  An observer that
calls a collective must therefore do so on every rank at the same step.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from petsc4py import PETSc

from parefg.errors import Interrupted, SolverError
from parefg.timestepping.schemes import State

# steps between collective PETSc.garbage_cleanup calls: the loop allocates no PETSc object
# per step, this frees what callbacks or observers may still drop
GARBAGE_EVERY = 1000


@dataclass(frozen=True)
class Step:
    """What the observers see after step ``n``.

    ``state`` is the simulation's level n (its vectors are reused two steps later: copy
    what you keep), ``row`` the step's per-step table row, ``last`` true when the loop ends
    after this step (the final step, or an agreed stop request): observers that write
    results write this step.
    """

    n: int
    state: State
    row: dict
    last: bool


class Observer(Protocol):
    def after_step(self, sim, step: Step) -> None: ...


class Callback:
    """An observer from a plain function ``callback(n, sim, state)``."""

    def __init__(self, callback):
        self.callback = callback

    def after_step(self, sim, step: Step) -> None:
        self.callback(step.n, sim, step.state)


def time_loop(sim, state: State, first: int, observers=(), stop=None, fail_at_step=None) -> State:
    """Steps ``first`` ... n_steps of ``sim`` from ``state`` (level first - 1).  Collective.

    After each step every observer's ``after_step`` runs, in order.  ``stop`` (a
    :class:`~parefg.io.monitors.StopRequest`) is asked after every step but the last;
    when a rank got a signal, every rank ends after the same step (observers see it with
    ``last`` set) and :class:`~parefg.errors.Interrupted` is raised.  ``fail_at_step``
    raises a SolverError before that step (the CLI's ``--fail-at-step``, for tests of
    failure handling).  Returns the final level.
    """
    n_steps = sim.scene.time.n_steps
    for n in range(first, n_steps + 1):
        if fail_at_step is not None and n == fail_at_step:
            raise SolverError(f"injected failure at step {n} (--fail-at-step)")
        state = sim.step(state, n)
        # the one decision per step every rank takes together (a signal at the final
        # step changes nothing: the run is complete)
        number = stop.agreed() if stop is not None and n < n_steps else 0
        step = Step(n=n, state=state, row=sim.history[-1], last=n == n_steps or bool(number))
        for observer in observers:
            observer.after_step(sim, step)
        if n % GARBAGE_EVERY == 0:
            PETSc.garbage_cleanup(sim.comm)
        if number:
            name = type(stop).name(number)
            raise Interrupted(f"interrupted by {name} after step {n} of {n_steps}", number)
    return state
