"""Checkpoint and restart of the time loop.

A checkpoint holds everything the loop needs to continue: the nodal parameters u, v, a,
the accumulated slip xi and the step's normal force C_n at the Gamma_C points, the step
number and the last per-step row (running sums of dissipation and external work).
Arrays are stored in the global, rank-independent order (nodes by their original index,
Gamma_C points by their global row), so a run may restart on a different number of
ranks.  Rank 0 writes the file (gathered arrays) to a temporary name and renames it, so a
crash during writing never destroys the previous checkpoint.

A checkpoint is valid only for the scene that wrote it.  It carries the effective scene
(``params_json``) and its fingerprint, a SHA-256 of the params that determine the
discretization and the time integration: every section except ``time.T`` (a restart may
extend a run), ``[output]`` and ``[solver]`` (they change what is written and how each
step is solved, not the solution), and the scene's name and description.  A restart
with a different fingerprint is refused, naming the differing keys; so is a checkpoint
at a step the scene does not have, with other node coordinates (the node cloud of a
changed .geo file), or with an array of the wrong shape or type.
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from parefg.errors import InputError
from parefg.parallel import call_on_root, gather_rows
from parefg.timestepping.schemes import State

VECTORS = ("u", "v", "a")
FORMAT = "parefg-checkpoint"
NODE_TOLERANCE = 1e-9  # relative to the domain's extent: same mesh up to gmsh's round-off
# params that may differ between the run that wrote a checkpoint and its restart
NOT_FINGERPRINTED = (("name",), ("description",), ("time", "T"), ("output",), ("solver",))


def fingerprinted_params(params: dict) -> dict:
    """``params`` without the keys a restart may change (NOT_FINGERPRINTED), JSON-normalised."""
    kept = json.loads(json.dumps(params, default=float))
    for path in NOT_FINGERPRINTED:
        table = kept
        for key in path[:-1]:
            table = table.get(key, {})
        table.pop(path[-1], None)
    return kept


def scene_fingerprint(params: dict) -> str:
    """SHA-256 (hex) of the canonical JSON of :func:`fingerprinted_params`."""
    canonical = json.dumps(fingerprinted_params(params), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(canonical.encode()).hexdigest()


def write_checkpoint(comm, path: Path, sim, state: State, step: int) -> None:
    """Write the loop state after ``step`` to ``path`` (atomically).  Collective."""
    disc = sim.disc
    node_rows = disc.nodes.rows
    arrays = {
        name: gather_rows(
            comm, node_rows, getattr(state, name).getArray().reshape(-1, 2), disc.n_nodes
        )
        for name in VECTORS
    }
    if sim.law is not None:
        arrays["slip"] = gather_rows(comm, disc.contact.rows, sim.law.slip, disc.n_contact)
        # the step's normal force C_n that a_n holds (parefg.mechanics.contact.end_level)
        arrays["contact_level"] = gather_rows(
            comm, disc.contact.rows, sim.law.level_pressure, disc.n_contact
        )
    arrays["nodes"] = gather_rows(comm, node_rows, disc.nodes.points, disc.n_nodes)
    if comm.rank == 0:
        partial = path.with_name(path.name + ".partial")
        with h5py.File(partial, "w") as handle:
            for name, values in arrays.items():
                handle.create_dataset(name, data=values)
            handle.attrs["format"] = FORMAT
            handle.attrs["step"] = step
            handle.attrs["params_json"] = json.dumps(sim.scene.params, default=float)
            handle.attrs["scene_fingerprint"] = scene_fingerprint(sim.scene.params)
            handle.attrs["history_json"] = json.dumps(sim.history[-1])
        os.replace(partial, path)
    comm.Barrier()


def read_checkpoint(comm, path: Path, sim) -> tuple[State, int, dict]:
    """Restore the loop state from ``path``; returns (state, step, last table row).  Collective.

    Rank 0 reads and validates the file (:func:`load_checkpoint`) and broadcasts the
    verdict, so a bad checkpoint raises the same InputError on every rank.  ``sim`` must
    have been started (``sim.start()``), which sets the shapes to check against.
    """
    disc = sim.disc
    nodes = gather_rows(comm, disc.nodes.rows, disc.nodes.points, disc.n_nodes)
    data = call_on_root(comm, load_checkpoint, path, sim, nodes)
    vectors = {}
    for name in VECTORS:
        vec = disc.create_vec()
        vec.setArray(data[name][disc.nodes.rows].ravel())
        vectors[name] = vec
    if sim.law is not None:
        sim.law.set_time(data["step"] * sim.scheme.dt)
        sim.law.slip = data["slip"][disc.contact.rows].copy()
        sim.law.level_pressure = data["contact_level"][disc.contact.rows].copy()
    return State(**vectors), data["step"], data["history"]


def load_checkpoint(path: Path, sim, nodes: np.ndarray) -> dict:
    """Read and validate a checkpoint for ``sim``'s scene (one rank; not collective).

    ``nodes`` (n_nodes, 2) are the scene's node coordinates in the global order: the
    checkpoint's must match (a changed .geo file or gmsh version moves the nodes).

    Returns the arrays (``u``, ``v``, ``a``, ``slip``, ``contact_level`` with contact),
    ``step`` and ``history`` (the last table row).  Raises InputError naming what is wrong.
    """
    where = f"--restart {_shown(path)}"
    _check_regular_file(where, path)
    try:
        with h5py.File(path, "r") as handle:
            _check_format(where, handle)
            attrs = _read_attributes(where, handle)
            # the scene first: a different scene explains wrong shapes better than they do
            _check_scene(where, attrs["params"], sim.scene.params)
            _check_step(where, attrs["step"], sim.scene.n_steps)
            _check_history(where, attrs["history"], sim.history[0], attrs["step"] * sim.scene.dt)
            shapes = _expected_shapes(sim)
            data = {name: _read_array(where, handle, name, shape) for name, shape in shapes.items()}
            _check_nodes(where, data.pop("nodes"), nodes)
    except (OSError, RuntimeError, TypeError, ValueError) as error:  # not HDF5, truncated
        raise InputError(f"{where}: not a readable parefg checkpoint ({_reason(error)})") from None
    data.update(step=attrs["step"], history=attrs["history"])
    return data


def _shown(path: Path) -> str:
    """A path as it appears in a message: at most 80 characters."""
    text = str(path)
    return text if len(text) <= 80 else f"{text[:50]}...{text[-20:]} ({len(text)} characters)"


def _reason(error: Exception) -> str:
    """The first line of an error's text (an OSError's strerror when it has one)."""
    text = getattr(error, "strerror", None) or str(error) or type(error).__name__
    return text.splitlines()[0]


def _check_regular_file(where: str, path: Path) -> None:
    """Refuse before opening: h5py blocks forever on a FIFO and fails obscurely on a directory."""
    try:
        mode = os.stat(path).st_mode
    except OSError as error:
        raise InputError(f"{where}: cannot read the checkpoint ({_reason(error)})") from None
    if not stat.S_ISREG(mode):
        kind = "a directory" if stat.S_ISDIR(mode) else "not a regular file"
        raise InputError(f"{where}: is {kind}; give the checkpoint.h5 of a run")


def _check_format(where: str, handle) -> None:
    if handle.attrs.get("format") == FORMAT:
        return
    if "history" in handle and "fields" in handle:
        raise InputError(
            f"{where}: is a parefg result file, not a checkpoint; give DIR/checkpoint.h5 "
            "of a run made with --checkpoint-every"
        )
    raise InputError(f"{where}: not a parefg checkpoint (no format = {FORMAT!r} attribute)")


def _read_attributes(where: str, handle) -> dict:
    """step (an integer), params and history (JSON objects)."""
    attrs: dict[str, Any] = {}
    try:
        step = handle.attrs["step"]
        params, history = (json.loads(handle.attrs[key]) for key in ("params_json", "history_json"))
    except KeyError as error:
        raise InputError(f"{where}: checkpoint lacks the attribute {error}") from None
    except (TypeError, ValueError) as error:  # not a string, not JSON
        raise InputError(f"{where}: checkpoint attribute is not valid JSON ({error})") from None
    if not isinstance(step, (int, np.integer)) or isinstance(step, (bool, np.bool_)):
        raise InputError(f"{where}: checkpoint step = {step!r}: must be an integer")
    if not isinstance(params, dict) or not isinstance(history, dict):
        raise InputError(f"{where}: checkpoint params_json and history_json must be JSON objects")
    attrs.update(step=int(step), params=params, history=history)
    return attrs


def _expected_shapes(sim) -> dict[str, tuple]:
    """Shape of every dataset a checkpoint for ``sim`` must hold (global order)."""
    shapes: dict[str, tuple] = {name: (sim.disc.n_nodes, 2) for name in (*VECTORS, "nodes")}
    if sim.law is not None:
        shapes["slip"] = (sim.disc.n_contact, *np.shape(sim.law.slip)[1:])
        shapes["contact_level"] = (sim.disc.n_contact,)
    return shapes


def _read_array(where: str, handle, name: str, shape: tuple) -> np.ndarray:
    """Dataset ``name``: present, a finite float array of exactly ``shape``."""
    dataset = handle.get(name)
    if not isinstance(dataset, h5py.Dataset):
        raise InputError(f"{where}: checkpoint lacks the dataset {name!r}")
    if dataset.shape != shape or dataset.dtype.kind != "f":
        raise InputError(
            f"{where}: checkpoint dataset {name!r} is {dataset.dtype} {dataset.shape}, the "
            f"scene needs float {shape}; restart with the scene that wrote it"
        )
    values = dataset[...].astype(float)
    if not np.all(np.isfinite(values)):
        raise InputError(f"{where}: checkpoint dataset {name!r} holds non-finite values")
    return values


def _check_nodes(where: str, stored: np.ndarray, nodes: np.ndarray) -> None:
    """The same node cloud, to round-off relative to the domain's extent."""
    extent = np.ptp(nodes, axis=0).max()
    moved = np.abs(stored - nodes).max(axis=1)
    if np.any(moved > NODE_TOLERANCE * extent):
        first = int(np.argmax(moved > NODE_TOLERANCE * extent))
        raise InputError(
            f"{where}: node {first} is at {_point(stored[first])} in the checkpoint, at "
            f"{_point(nodes[first])} now: another node cloud (changed .geo file or gmsh?)"
        )


def _point(xy: np.ndarray) -> str:
    return f"({xy[0]:.6g}, {xy[1]:.6g})"


def _flatten(tree, prefix: str = "") -> dict:
    """Nested params -> {"section.key": value}."""
    if not isinstance(tree, dict):
        return {prefix: tree}
    flat = {}
    for key, value in tree.items():
        flat.update(_flatten(value, f"{prefix}.{key}" if prefix else key))
    return flat


def _check_scene(where: str, stored: dict, current: dict) -> None:
    """Same fingerprint as the scene of this run, or an error naming the differing keys."""
    if scene_fingerprint(stored) == scene_fingerprint(current):
        return
    old, new = (_flatten(fingerprinted_params(p)) for p in (stored, current))
    differing = sorted(key for key in old.keys() | new.keys() if old.get(key) != new.get(key))
    shown = ", ".join(
        f"{key} ({_value(old.get(key))} in the checkpoint, {_value(new.get(key))} now)"
        for key in differing[:4]
    )
    more = f" and {len(differing) - 4} more" if len(differing) > 4 else ""
    raise InputError(
        f"{where}: written by a different scene: {shown}{more}; restart with the scene "
        "that wrote it (only time.T, [output] and [solver] may change)"
    )


def _value(value) -> str:
    text = "absent" if value is None else json.dumps(value)
    return text if len(text) <= 30 else text[:27] + "..."


def _check_step(where: str, step: int, n_steps: int) -> None:
    """0 <= step < n_steps: a restart must have steps left to do."""
    if step < 0:
        raise InputError(f"{where}: checkpoint step = {step}: must be >= 0")
    if step >= n_steps:
        raise InputError(
            f"{where}: checkpoint is at step {step}, the scene has {n_steps} steps: nothing "
            "left to do (raise time.T to continue the run)"
        )


def _check_history(where: str, row: dict, template: dict, time: float) -> None:
    """The last table row: the same keys as this run's rows, finite numbers, t = step dt."""
    if set(row) != set(template):
        missing = ", ".join(sorted(set(template) ^ set(row)))
        raise InputError(f"{where}: checkpoint history_json has other keys than a run ({missing})")
    values = list(row.values())
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values) or not (
        np.all(np.isfinite(values))
    ):
        raise InputError(f"{where}: checkpoint history_json must hold finite numbers")
    if abs(row["time"] - time) > 1e-9 * max(abs(time), 1.0):
        raise InputError(
            f"{where}: checkpoint history time {row['time']!r} is not step * dt = {time:g}"
        )
