"""Checkpoint and restart of the time loop.

A checkpoint holds everything the loop needs to continue: the nodal parameters u, v, a,
the accumulated slip xi at the Gamma_C points, the step number and the last per-step row
(running sums of dissipation and external work).  Arrays are stored in the global,
rank-independent order (nodes by their original index, Gamma_C points by their global
row), so a run may restart on a different number of ranks.  Rank 0 writes the file
(gathered arrays) to a temporary name and renames it, so a crash during writing never
destroys the previous checkpoint.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import h5py
import numpy as np

from parefg.errors import InputError
from parefg.timestepping import State

VECTORS = ("u", "v", "a")


def _gather_rows(comm, rows: np.ndarray, values: np.ndarray, n_rows: int):
    """Assemble a global (n_rows, ...) array on rank 0 from each rank's rows.  Collective."""
    pieces = comm.gather((rows, values), root=0)
    if comm.rank != 0:
        return None
    out = np.zeros((n_rows, *values.shape[1:]))
    for piece_rows, piece_values in pieces:
        out[piece_rows] = piece_values
    return out


def write_checkpoint(comm, path: Path, sim, state: State, step: int) -> None:
    """Write the loop state after ``step`` to ``path`` (atomically).  Collective."""
    disc = sim.disc
    node_rows = disc.nodes.rows
    arrays = {
        name: _gather_rows(
            comm, node_rows, getattr(state, name).getArray().reshape(-1, 2), disc.n_nodes
        )
        for name in VECTORS
    }
    if sim.law is not None:
        arrays["slip"] = _gather_rows(comm, disc.contact.rows, sim.law.slip, disc.n_contact)
    if comm.rank == 0:
        partial = path.with_name(path.name + ".partial")
        with h5py.File(partial, "w") as handle:
            for name, values in arrays.items():
                handle.create_dataset(name, data=values)
            handle.attrs["step"] = step
            handle.attrs["params_json"] = json.dumps(sim.scene.params, default=float)
            handle.attrs["history_json"] = json.dumps(sim.history[-1])
        os.replace(partial, path)
    comm.Barrier()


def read_checkpoint(comm, path: Path, sim) -> tuple[State, int, dict]:
    """Restore the loop state from ``path``; returns (state, step, last table row).  Collective.

    The scene must discretize to the same node cloud (same n_nodes) as the checkpoint.
    """
    disc = sim.disc
    message, data = None, None
    if comm.rank == 0:
        try:
            with h5py.File(path, "r") as handle:
                data = {name: handle[name][...] for name in handle}
                data["step"] = int(handle.attrs["step"])
                data["history"] = json.loads(handle.attrs["history_json"])
        except (OSError, KeyError) as error:
            message = f"--restart {path}: not a readable parefg checkpoint ({error})"
        if data is not None and data["u"].shape[0] != disc.n_nodes:
            message = (
                f"--restart {path}: checkpoint has {data['u'].shape[0]} nodes, the scene "
                f"has {disc.n_nodes}; restart with the scene that wrote it"
            )
    message, data = comm.bcast((message, data), root=0)
    if message:
        raise InputError(message)
    vectors = {}
    for name in VECTORS:
        vec = disc.create_vec()
        vec.setArray(data[name][disc.nodes.rows].ravel())
        vectors[name] = vec
    if sim.law is not None:
        sim.law.set_time(data["step"] * sim.scheme.k)
        sim.law.slip = data["slip"][disc.contact.rows].copy()
    return State(**vectors), data["step"], data["history"]
