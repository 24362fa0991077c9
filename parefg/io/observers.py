"""Observers of the time loop that write: results at the output steps, checkpoints.

Each has ``after_step(sim, step)`` (see :mod:`parefg.timestepping.loop`) and is
collective: every rank calls it after the same step.  Their time counts as the run's
"output" phase.
"""

from __future__ import annotations

from pathlib import Path

from parefg.io.checkpoint import write_checkpoint
from parefg.io.output import ResultWriter
from parefg.mechanics.elasticity import von_mises
from parefg.profiling import phase
from parefg.scene.schema import OUTPUT_FIELDS


def is_output_step(n: int, scene) -> bool:
    """Step n (0: the initial state) is written: the final one, and every ``every``-th."""
    every = scene.output.every
    return n == scene.time.n_steps or (every > 0 and n % every == 0)


def output_fields(sim, state) -> tuple[dict, dict]:
    """The [output] fields: at the nodes u_h, velocity, acceleration, von Mises; the contact
    state at the Gamma_C points.  Collective.

    Only what the scene asks for is computed: without von_mises the nodal gradient
    operator (the largest operator) is never built.  Before the first step the status
    is open and the tangential traction 0 (no step has been solved yet).
    """
    nodes, scene, wanted = sim.disc.nodes, sim.scene, set(sim.scene.output.fields)
    vectors = {"u": state.u, "v": state.v, "a": state.a}
    # each node field writes one dataset, named by the registry
    node_fields = {
        OUTPUT_FIELDS[key][0]: nodes.evaluate(vector)
        for key, vector in vectors.items()
        if key in wanted
    }
    if "von_mises" in wanted:
        grads = nodes.evaluate_gradient(state.u)
        node_fields[OUTPUT_FIELDS["von_mises"][0]] = von_mises(
            scene.material.lam, scene.material.mu, grads
        )
    contact_fields = {}
    if sim.law is not None and "contact" in wanted:
        law = sim.law
        un = law.kinematics(state.u)[0]  # Nitsche: u_nu - sigma_nu / gamma, its pressure's
        pressure, friction = law.tractions(law.pressure(un), law.step_friction)
        values = {
            "gap": law.gap - law.normal_displacement(state.u),
            "normal_pressure": pressure,
            "tangential_traction": friction,
            "status": law.step_status,
        }
        contact_fields = {name: values[name] for name in OUTPUT_FIELDS["contact"]}
    return node_fields, contact_fields


class ResultsObserver:
    """Appends every step's row to ``writer`` and writes the fields at the output steps
    (and at the step a stop request ends the run on)."""

    def __init__(self, writer: ResultWriter):
        self.writer = writer

    def write_initial(self, sim, state) -> None:
        """The t = 0 row, and the t = 0 fields when step 0 is an output step.  Collective."""
        with phase(sim.timings, "output"):
            self.writer.append_history(sim.history[0])
            if is_output_step(0, sim.scene):
                self.writer.write_step(0, 0.0, *output_fields(sim, state))

    def after_step(self, sim, step) -> None:
        with phase(sim.timings, "output"):
            self.writer.append_history(step.row)
            if is_output_step(step.n, sim.scene) or step.last:
                node_fields, contact_fields = output_fields(sim, step.state)
                sim.check_fields(step.n, {**node_fields, **contact_fields})
                self.writer.write_step(step.n, step.row["time"], node_fields, contact_fields)


class CheckpointObserver:
    """Writes ``path`` (atomically replaced) every ``every`` steps."""

    def __init__(self, path: Path, every: int):
        self.path, self.every = path, every

    def after_step(self, sim, step) -> None:
        if step.n % self.every == 0:
            with phase(sim.timings, "output"):
                write_checkpoint(sim.comm, self.path, sim, step.state, step.n)
