"""The Scene: one frozen dataclass per section of the scene file (SPEC 6).

The sections mirror the TOML: ``scene.time.dt`` is ``[time] dt``, ``scene.material.lam``
is ``[material] lam`` (given, or computed from E and nu), ``scene.loads.f`` is ``[loads]
f``.  Each section holds the validated values with the defaults filled in (the effective
scene, also kept as plain TOML data in ``Scene.params``) and what follows from them
alone (``time.n_steps``, ``time.dynamic``); expressions are vectorized callables
(:mod:`parefg.scene.fields`).  Built by :func:`parefg.scene.loader.load_scene`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # annotations only
    from parefg.scene.numeric import BoundaryCondition, CompiledField, ExactSolution


@dataclass(frozen=True)
class DiscretizationSection:
    """``[discretization]``: the node spacing, the MLS approximation and the quadrature."""

    h: float
    degree: int  # m
    weight: str  # a name of parefg.discretization.weights.WEIGHTS
    support: float  # dilation s
    quadrature: int  # Gauss points per cell direction
    cells: str  # a parefg.geometry.cells.CellType
    integration: str  # "gauss" or "vci" (parefg.scene.schema.INTEGRATIONS)
    jitter: float  # 0 when absent
    seed: int  # 0 when absent


@dataclass(frozen=True)
class MaterialSection:
    """``[material]``: both pairs of elastic constants (plane strain) and the density."""

    E: float
    nu: float
    lam: float
    mu: float
    rho: float


@dataclass(frozen=True)
class TimeSection:
    """``[time]``: the scheme and its parameters; n_steps = T / dt."""

    scheme: str  # a name of parefg.timestepping.schemes.SCHEMES
    dynamic: bool  # the scheme has inertia (SCHEMES[scheme].dynamic)
    T: float
    dt: float
    beta: float
    gamma: float
    rho_inf: float | None  # generalized-alpha only
    contact_force: str  # a name of parefg.mechanics.normal_force.CONTACT_FORCES
    n_steps: int


@dataclass(frozen=True)
class PenaltySection:
    """``[penalty]``: the factor of each kind of parefg.mechanics.penalty.PENALTY_KINDS."""

    alpha_dirichlet: float
    alpha_contact: float
    alpha_friction: float


@dataclass(frozen=True)
class InitialSection:
    """``[initial]``: u_0 and v_0, and the derivatives of u_0 the initial state needs."""

    u: CompiledField
    v: CompiledField
    # grad u0 (x, y) -> (2, 2, n) and div sigma(u0) (x, y) -> (2, n); None where u0 = 0
    grad: CompiledField | None
    div_stress: CompiledField | None


@dataclass(frozen=True)
class LoadsSection:
    """``[loads]``: the body force f(x, y, t)."""

    f: CompiledField


@dataclass(frozen=True)
class OutputSection:
    """``[output]``: steps between outputs (0: final step only) and the fields written."""

    every: int
    fields: tuple[str, ...]


@dataclass(frozen=True)
class SolverSection:
    """``[solver]``: the method and the PETSc options of the table (method excluded)."""

    method: str  # a name of parefg.timestepping.linear_solver.SOLVER_METHODS
    options: dict[str, str]


@dataclass(frozen=True)
class Scene:
    """A validated scene: the effective ``params`` and its sections.

    ``domain`` is the ``[domain]`` table (read by the shape's builder), ``boundaries`` the
    ``[boundary.NAME]`` tables as conditions by part name, ``exact`` the ``[exact]``
    solution (None without one).
    """

    name: str
    params: dict
    source_dir: Path
    domain: dict
    part_names: list[str]
    discretization: DiscretizationSection
    material: MaterialSection
    time: TimeSection
    penalty: PenaltySection
    boundaries: dict[str, BoundaryCondition]
    initial: InitialSection
    loads: LoadsSection
    exact: ExactSolution | None
    output: OutputSection
    solver: SolverSection
