"""Scenes: TOML problem descriptions, validated and completed (SPEC 6, 9).

:func:`load_scene` reads a built-in scene or a TOML file, applies
``section.key=value`` overrides, checks every section and key against the
schema (:mod:`parefg.scene.schema`: one-line :class:`InputError` naming the key),
writes the defaults back so that ``Scene.params`` is the effective scene, and builds the
:class:`~parefg.scene.sections.Scene`, one frozen section per TOML section, with the
expressions turned into vectorized callables (:mod:`parefg.scene.fields`).  Given
``[exact] u``, the data the scene leaves out are derived from it
(:mod:`parefg.scene.manufactured`).

Derived data stay out of ``params`` (they follow from ``[exact]``), so loading
the effective scene again gives the same scene.
"""

from __future__ import annotations

import copy
import tomllib
from collections.abc import Sequence
from pathlib import Path

from parefg.errors import InputError
from parefg.mechanics.penalty import PENALTY_KINDS
from parefg.scene import scene_cache
from parefg.scene.schema import elastic_constants, plain_name, step_count, validate
from parefg.scene.sections import (
    DiscretizationSection,
    InitialSection,
    LoadsSection,
    MaterialSection,
    OutputSection,
    PenaltySection,
    Scene,
    SolverSection,
    TimeSection,
)
from parefg.timestepping.schemes import SCHEMES

SCENES_DIR = Path(__file__).with_name("builtin")
MAX_SCENE_BYTES = 2**24  # a scene is a few hundred bytes; a long polygon a few hundred KB


def builtin_scenes() -> dict[str, str]:
    """Built-in scene names -> their description (``description`` key or first comment line)."""
    scenes = {}
    for path in sorted(SCENES_DIR.glob("*.toml")):
        text = path.read_text()
        first = text.lstrip().splitlines()[0] if text.strip() else ""
        described = tomllib.loads(text).get("description")
        scenes[path.stem] = described or first.lstrip("#").strip()
    return scenes


def load_scene(
    source: str, overrides: Sequence[str] = (), command_line: dict[str, str] | None = None
) -> Scene:
    """Read, override, validate and complete a scene.

    Not collective (every rank may call it; the result is the same).

    Parameters
    ----------
    source
        A built-in scene name (see :func:`builtin_scenes`) or a path to a TOML file.
    overrides
        ``"section.key=value"`` strings, e.g. ``"discretization.h=0.05"`` or
        ``"boundary.bottom.friction=0"``; value is read as a TOML value, else as a string.
    command_line
        The step solver's PETSc options from the command line (``{"ksp_type": "cg"}``):
        like the scene's ``[solver]`` options, they decide whether the defaults must
        suit a symmetric solver (parefg.scene.schema.wants_symmetric).

    Raises
    ------
    InputError
        One line, ``scene NAME: key ...: what is wrong``, for a missing file, a
        TOML syntax error, a bad override or any schema violation.
    """
    name, raw, source_dir = _read_source(source)
    where = f"scene {name}"
    for text in overrides:
        _apply_override(raw, text, where)
    params, part_names = validate(where, raw, name, source_dir, command_line)
    return _build(where, params, part_names, source_dir)


def _read_source(source: str) -> tuple[str, dict, Path]:
    """(name, raw TOML dict, directory) of a built-in name or a TOML path."""
    builtin = SCENES_DIR / f"{source}.toml"
    looks_like_path = source.endswith(".toml") or "/" in source
    path = builtin if not looks_like_path and builtin.is_file() else Path(source)
    if not path.is_file():
        known = ", ".join(builtin_scenes())
        raise InputError(f"scene {source!r}: no such built-in scene or file (built-in: {known})")
    name = plain_name(path.stem)  # the default output directory is runs/<name>
    try:
        if path.stat().st_size > MAX_SCENE_BYTES:
            size = path.stat().st_size
            raise InputError(f"scene {name}: {path} has {size} bytes (at most {MAX_SCENE_BYTES})")
        with path.open("rb") as stream:
            raw = tomllib.load(stream)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"scene {name}: TOML syntax error in {path}: {exc}") from None
    except (RecursionError, MemoryError, ValueError) as exc:
        raise InputError(f"scene {name}: cannot parse {path}: {_toml_failure(exc)}") from None
    except OSError as exc:
        raise InputError(f"scene {name}: cannot read {path}: {exc.strerror}") from None
    return name, raw, path.resolve().parent


def _toml_failure(exc: Exception) -> str:
    """Why tomllib failed other than by a syntax error, in one line."""
    if isinstance(exc, RecursionError):
        return "arrays or tables nested too deeply"
    if isinstance(exc, MemoryError):
        return "out of memory"
    # Python refuses to convert integers of more than 4300 digits
    return str(exc).split(";")[0].split(":")[0]


def _apply_override(raw: dict, text: str, where: str) -> None:
    """Set ``raw[section][...][key] = value`` from ``"section.key=value"``."""
    path, equals, value_text = text.partition("=")
    keys = path.strip().split(".")
    if not equals or len(keys) < 2 or not all(keys):
        raise InputError(f"{where}: --set {text!r}: expected section.key=value")
    try:
        value = tomllib.loads("v = " + value_text)["v"]
    except tomllib.TOMLDecodeError:
        value = value_text.strip()
    except (RecursionError, MemoryError, ValueError) as exc:
        shown = repr(text) if len(text) <= 60 else repr(text[:57] + "...")
        raise InputError(f"{where}: --set {shown}: {_toml_failure(exc)}") from None
    table = raw
    for depth, key in enumerate(keys[:-1]):
        table = table.setdefault(key, {})
        if not isinstance(table, dict):
            inner = ".".join(keys[: depth + 1])
            raise InputError(f"{where}: --set {text!r}: {inner} is not a table")
    table[keys[-1]] = value


def _build(where: str, params: dict, part_names: list[str], source_dir: Path) -> Scene:
    """Turn validated params into a Scene with callables (compiled data cached, see
    :mod:`parefg.scene.scene_cache`)."""
    material, time = _material(params["material"]), _time(where, params["time"])
    key = scene_cache.scene_key(params, time.dynamic)
    data = scene_cache.load(key)
    if data is None:
        data = _derive(where, params, material, time.dynamic)
        scene_cache.store(key, data)
    output = params["output"]
    return Scene(
        name=params["name"],
        params=params,
        source_dir=source_dir,
        domain=copy.deepcopy(params["domain"]),
        part_names=list(part_names),
        discretization=_discretization(params["discretization"]),
        material=material,
        time=time,
        penalty=PenaltySection(
            **{f"alpha_{kind}": params["penalty"][f"alpha_{kind}"] for kind in PENALTY_KINDS}
        ),
        boundaries=data["boundaries"],
        loads=LoadsSection(f=data["body_force"]),
        initial=InitialSection(
            u=data["initial_u"],
            v=data["initial_v"],
            grad=data["initial_grad"],
            div_stress=data["initial_div_stress"],
        ),
        exact=data["exact"],
        output=OutputSection(every=output["every"], fields=tuple(output["fields"])),
        solver=_solver(params["solver"]),
    )


def _solver(table: dict) -> SolverSection:
    """The [solver] section: the method, and the rest of the table as PETSc options."""
    options = {key: value for key, value in table.items() if key != "method"}
    return SolverSection(method=table["method"], options=options)


def _discretization(table: dict) -> DiscretizationSection:
    """The [discretization] section; jitter and seed are 0 when absent (no jitter)."""
    keys = ("h", "degree", "weight", "support", "quadrature", "cells", "integration")
    return DiscretizationSection(
        **{key: table[key] for key in keys},
        jitter=table.get("jitter", 0.0),
        seed=table.get("seed", 0),
    )


def _material(table: dict) -> MaterialSection:
    """The [material] section with both pairs of elastic constants."""
    E, nu, lam, mu = elastic_constants(table)
    return MaterialSection(E=E, nu=nu, lam=lam, mu=mu, rho=table["rho"])


def _time(where: str, table: dict) -> TimeSection:
    """The [time] section, with the step count and whether the scheme has inertia."""
    return TimeSection(
        **{key: table[key] for key in ("scheme", "T", "dt", "beta", "gamma", "contact_force")},
        dynamic=SCHEMES[table["scheme"]].dynamic,
        rho_inf=table.get("rho_inf"),
        n_steps=step_count(where, table),
    )


def _derive(where: str, params: dict, material: MaterialSection, dynamic: bool) -> dict:
    """The compiled data of a scene (boundaries, body_force, initial_*, exact: what the
    scene cache keeps), derived symbolically; raises InputError for a bad expression."""
    # sympy (~1/2 s to import) only where expressions are derived: not for `parefg scenes`,
    # nor for a run of a scene whose compiled data are cached
    from parefg.scene import fields
    from parefg.scene.checks import SignChecks
    from parefg.scene.manufactured import ManufacturedSolution, initial_elasticity
    from parefg.scene.symbolic import DerivativeBudget

    lam, mu, rho = material.lam, material.mu, material.rho
    manufactured = None
    if "exact" in params:
        exact_u = fields.scene_expressions(where, "exact.u", params["exact"]["u"])
        derivatives = DerivativeBudget(where, "exact.u")
        manufactured = ManufacturedSolution(exact_u, lam, mu, rho, dynamic, derivatives)
    checks = SignChecks(where, params, material.E)
    initial_grad, initial_div_stress = initial_elasticity(
        where, params["initial"].get("u"), manufactured, lam, mu, rho
    )
    return {
        "boundaries": {
            name: fields.boundary_condition(where, name, table, manufactured, checks)
            for name, table in params.get("boundary", {}).items()
        },
        "body_force": fields.vector_field(
            where, "loads.f", params["loads"].get("f"), manufactured, "f"
        ),
        "initial_u": fields.initial_field(where, "u", params["initial"].get("u"), manufactured),
        "initial_v": fields.initial_field(where, "v", params["initial"].get("v"), manufactured),
        "initial_grad": initial_grad,
        "initial_div_stress": initial_div_stress,
        "exact": manufactured.solution(params["exact"]["u"]) if manufactured else None,
    }
