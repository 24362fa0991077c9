"""Checkpoint and restart of the time loop.

A checkpoint holds everything the loop needs to continue: the nodal parameters u, v, a,
the accumulated slip xi and the step's normal force C_n at the Gamma_C points, the step
number and the last per-step row (running sums of dissipation and external work).
The state comes from :meth:`Simulation.snapshot` and goes back through
:meth:`Simulation.restore`.  Arrays are stored in the global, rank-independent order
(nodes by their original index, Gamma_C points by their global row), so a run may restart
on a different number of ranks.  Every rank writes and reads one block of rows of each
array, collectively (:class:`~parefg.io.rows.BlockRows`): nothing is gathered to rank 0
nor broadcast back, and no rank holds more than its share.  The file is written to a
temporary name that rank 0 renames once every rank has closed it, so a crash during
writing never destroys the previous checkpoint.

A checkpoint is valid only for the scene that wrote it.  It carries the effective scene
(``params_json``) and its fingerprint, a SHA-256 of the params that determine the
discretization and the time integration: every section except ``time.T`` (a restart may
extend a run), ``[output]`` and ``[solver]`` (they change what is written and how each
step is solved, not the solution; the solver does choose some discretization defaults,
e.g. the iterative method's supports, and those are in the fingerprinted
``[discretization]``), and the scene's name and description.  A restart
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
from mpi4py import MPI

from parefg.errors import InputError
from parefg.io.hdf5 import open_h5
from parefg.io.rows import BlockRows
from parefg.parallel import call_on_root, raise_everywhere, raise_unless_everywhere

VECTORS = ("u", "v", "a")
CONTACT_ARRAYS = ("slip", "contact_level")  # at the Gamma_C points, with a contact boundary
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


def write_checkpoint(comm, path: Path, sim, state, step: int) -> None:
    """Write the loop state after ``step`` to ``path`` (atomically).  Collective."""
    snapshot = sim.snapshot(state, step)
    attributes = comm.bcast(
        {
            "format": FORMAT,
            "step": step,
            "params_json": json.dumps(sim.scene.params, default=float),
            "scene_fingerprint": scene_fingerprint(sim.scene.params),
            "history_json": json.dumps(snapshot["history"]),
        },
        root=0,
    )
    partial = path.with_name(path.name + ".partial")
    with open_h5(comm, partial, "w") as handle:
        for name, rows in _layout(comm, sim):
            values = sim.disc.nodes.points if name == "nodes" else snapshot[name]
            values = np.asarray(values, dtype=np.float64)
            shape = (rows.n_global, *values.shape[1:])
            dataset = handle.create_dataset(name, shape=shape, dtype=np.float64)
            rows.write(dataset, values)
        handle.attrs.update(attributes)
    error = None
    if comm.rank == 0:
        try:
            os.replace(partial, path)
        except OSError as failure:
            error = OSError(f"cannot write the checkpoint {path}: {_reason(failure)}")
    raise_everywhere(comm, error, root=0)


def _layout(comm, sim) -> list[tuple[str, BlockRows]]:
    """(dataset name, rows) of every array of a checkpoint of ``sim``.  Collective."""
    disc = sim.disc
    node_rows = BlockRows(comm, disc.nodes.rows, disc.n_nodes, "node")
    layout = [(name, node_rows) for name in (*VECTORS, "nodes")]
    if sim.law is not None:
        contact_rows = BlockRows(comm, disc.contact.rows, disc.n_contact, "contact")
        layout += [(name, contact_rows) for name in CONTACT_ARRAYS]
    return layout


def read_checkpoint(comm, path: Path, sim) -> dict:
    """The snapshot stored in ``path``, this rank's part, for :meth:`Simulation.restore`.

    Rank 0 validates the file's attributes and dataset shapes (:func:`check_checkpoint`)
    and broadcasts the verdict, so a bad checkpoint raises the same InputError on every
    rank.  Then every rank reads the block of rows its share covers, collectively, and
    the rows move to the ranks that own them; the values (finite) and the node positions
    (the same cloud) are checked on each rank's own part.  ``sim`` must have been started
    (``sim.start()``), which sets the shapes to check against.  Collective.
    """
    where = f"--restart {_shown(path)}"
    attrs = call_on_root(comm, check_checkpoint, path, sim)
    snapshot: dict[str, Any] = dict(step=attrs["step"], history=attrs["history"])
    snapshot["time"] = attrs["step"] * sim.scheme.dt
    with open_h5(comm, path, "r") as handle:
        for name, rows in _layout(comm, sim):
            values = rows.read(handle[name]).astype(float, copy=False)
            finite = bool(np.all(np.isfinite(values)))
            message = f"{where}: checkpoint dataset {name!r} holds non-finite values"
            raise_unless_everywhere(comm, finite, InputError(message))
            if name == "nodes":
                _check_nodes(comm, where, values, sim.disc.nodes.points, sim.disc.nodes.rows)
            else:
                snapshot[name] = values
    return snapshot


def check_checkpoint(path: Path, sim) -> dict:
    """Validate a checkpoint for ``sim``'s scene without reading its arrays (one rank).

    Checks the file type, the format mark, the attributes (scene fingerprint, step, last
    table row) and the shape and type of every dataset.  Returns ``step`` and ``history``
    (the last table row).  Raises InputError naming what is wrong.
    """
    where = f"--restart {_shown(path)}"
    _check_regular_file(where, path)
    try:
        with h5py.File(path, "r") as handle:
            _check_format(where, handle)
            attrs = _read_attributes(where, handle)
            # the scene first: a different scene explains wrong shapes better than they do
            _check_scene(where, attrs["params"], sim.scene.params)
            _check_step(where, attrs["step"], sim.scene.time.n_steps)
            _check_history(
                where, attrs["history"], sim.history[0], attrs["step"] * sim.scene.time.dt
            )
            for name, shape in _expected_shapes(sim).items():
                _check_dataset(where, handle, name, shape)
    except (OSError, RuntimeError, TypeError, ValueError) as error:  # not HDF5, truncated
        raise InputError(f"{where}: not a readable parefg checkpoint ({_reason(error)})") from None
    return dict(step=attrs["step"], history=attrs["history"])


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


def _check_dataset(where: str, handle, name: str, shape: tuple) -> None:
    """Dataset ``name``: present, a float array of exactly ``shape``."""
    dataset = handle.get(name)
    if not isinstance(dataset, h5py.Dataset):
        raise InputError(f"{where}: checkpoint lacks the dataset {name!r}")
    if dataset.shape != shape or dataset.dtype.kind != "f":
        raise InputError(
            f"{where}: checkpoint dataset {name!r} is {dataset.dtype} {dataset.shape}, the "
            f"scene needs float {shape}; restart with the scene that wrote it"
        )


def _check_nodes(comm, where: str, stored: np.ndarray, nodes: np.ndarray, rows) -> None:
    """The same node cloud, to round-off relative to the domain's extent.  Collective.

    Each rank compares its own nodes; the message names the first moved node of the file.
    """
    local = np.concatenate([-nodes.min(axis=0, initial=np.inf), nodes.max(axis=0, initial=-np.inf)])
    bounds = np.empty(4)  # -x_min, -y_min, x_max, y_max over all ranks
    comm.Allreduce(local, bounds, op=MPI.MAX)
    extent = np.max(bounds[2:] + bounds[:2])
    moved = np.abs(stored - nodes).max(axis=1, initial=0.0) > NODE_TOLERANCE * extent
    first = comm.allreduce(int(np.min(rows[moved], initial=np.iinfo(np.int64).max)), op=MPI.MIN)
    error = None
    if moved.any() and first in rows[moved]:
        here = int(np.flatnonzero(rows == first)[0])
        error = InputError(
            f"{where}: node {first} is at {_point(stored[here])} in the checkpoint, at "
            f"{_point(nodes[here])} now: another node cloud or numbering (a changed .geo "
            "file, another gmsh or parefg version?)"
        )
    raise_everywhere(comm, error)


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
    hint = ""
    if any(key.startswith("discretization.") for key in differing):
        # the defaults of support, integration and quadrature follow the degree and the
        # linear solver: a restart with another solver changes them unless they are set
        hint = " or set the checkpoint's discretization values explicitly (--set)"
    raise InputError(
        f"{where}: written by a different scene: {shown}{more}; restart with the scene "
        f"that wrote it (only time.T, [output] and [solver] may change){hint}"
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
