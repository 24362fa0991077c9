"""The loads of a run: F(t) = int f . phi + int_{Gamma_N} p . phi, and the Dirichlet data.

A datum that is time-separable, g = sum_k a_k(t) g_k(x) (parefg.scene.separable), is
integrated once per run, F_k = int g_k . phi, and a step forms F(t) = sum_k a_k(t) F_k
with one ``maxpy``: K numbers per step instead of the datum at every quadrature point
and a product with the transposed value operator per component.  The Dirichlet data
ubar(t) at the Gamma_D points are sum_k a_k(t) ubar_k likewise, evaluated once per t
(the step's load and the energy ledger share them), and their load L^T w ubar(t) is
sum_k a_k(t) L^T w ubar_k.  Other data keep their per-point evaluation; both paths are
checked by the run's :class:`~parefg.guards.DataGuard` (see :class:`PointDatum`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from petsc4py import PETSc

from parefg.boundary import BoundaryKind
from parefg.guards import DataGuard, PointDatum

#: values (*components, n) at the points -> ``out`` = their load vector (collective)
Integrate = Callable[[np.ndarray, PETSc.Vec], None]


class IntegratedDatum:
    """A :class:`PointDatum` and its load vector.  Construction is collective.

    ``vectors`` holds the F_k of a separable datum (empty otherwise), integrated together
    by ``integrate_many`` (parts (K, 2, n), vectors) when given (one MLS pass over a domain
    without its value operator), else one by one.
    """

    def __init__(self, datum: PointDatum, integrate: Integrate, create_vec, integrate_many=None):
        self.datum, self.integrate = datum, integrate
        parts: np.ndarray | list = [] if datum.space is None else datum.space
        self.vectors: list[PETSc.Vec] = [create_vec() for _ in parts]
        if integrate_many is not None and len(parts):
            integrate_many(parts, self.vectors)
            return
        for part, vector in zip(parts, self.vectors, strict=True):
            integrate(part, vector)

    def add(self, t: float, out: PETSc.Vec, work: PETSc.Vec) -> None:
        """out += the load of the datum at t (``work``: a scratch vector).  Collective."""
        a = self.datum.coefficients(t)  # the same on every rank (a collective datum)
        if a is None:
            self.integrate(self.datum.values(t), work)
            out.axpy(1.0, work)
        else:
            out.maxpy(a, self.vectors)


class ExternalLoads:
    """F(t) and the Dirichlet data of ``scene`` on ``disc``.  Construction is collective.

    Bad values go to ``guard`` (checked by whoever drives the run before a solve).
    """

    CACHED_TIMES = 2  # ubar(t) kept per part: t_n and, for generalized-alpha, t_{n-1}

    def __init__(self, comm, disc, scene, guard: DataGuard):
        self.disc = disc
        self._work = disc.create_vec()
        domain = disc.domain
        force = PointDatum(
            guard, ("loads", "f"), scene.loads.f, *_coordinates(domain.points), comm=comm
        )
        self.forces_terms = [
            IntegratedDatum(
                force, _point_integral(domain), disc.create_vec, _point_integrals(domain)
            )
        ]
        # f_k at every Gauss point (~1 KB per DOF at m = 2) are integrated; the points
        # themselves may be released by the domain (Simulation.start)
        force.release_space(again=lambda: _coordinates(domain.restore_points()[0]))
        self.dirichlet: dict[str, IntegratedDatum] = {}
        for name, bc in scene.boundaries.items():
            if bc.kind == BoundaryKind.NEUMANN:
                datum = _boundary_datum(comm, guard, disc, name, "traction", bc.traction)
                integral = _point_integral(disc.boundary[name])
                self.forces_terms.append(IntegratedDatum(datum, integral, disc.create_vec))
            elif bc.kind == BoundaryKind.DIRICHLET:
                datum = _boundary_datum(comm, guard, disc, name, "value", bc.value)
                integral = _dirichlet_integral(disc.dirichlet_parts[name])
                self.dirichlet[name] = IntegratedDatum(datum, integral, disc.create_vec)
        self._ubar: dict[str, dict[float, np.ndarray]] = {name: {} for name in self.dirichlet}

    @property
    def integrates_domain(self) -> bool:
        """Whether the body force is integrated at every step (not time-separable): the
        domain's value operator is then used by every step."""
        return self.forces_terms[0].datum.scale is None

    def forces(self, t: float, out: PETSc.Vec) -> PETSc.Vec:
        """out = F(t), body force and Neumann tractions against the shape functions.  Collective."""
        out.set(0.0)
        for term in self.forces_terms:
            term.add(t, out, self._work)
        return out

    def dirichlet_value(self, name: str, t: float) -> np.ndarray:
        """ubar(t) at the points of Dirichlet part ``name``, (n, 2), read-only.  Not collective.

        Evaluated (and checked by the guard) at the first call for t, then cached.
        """
        cache = self._ubar[name]
        if t not in cache:
            if len(cache) >= self.CACHED_TIMES:
                del cache[next(iter(cache))]
            value = self.dirichlet[name].datum.values(t).T
            value.flags.writeable = False
            cache[t] = value
        return cache[t]

    def add_dirichlet(self, t: float, out: PETSc.Vec) -> None:
        """out += L^T (w ubar(t)) of every Dirichlet part.  Collective."""
        for name, term in self.dirichlet.items():
            ubar = self.dirichlet_value(name, t)  # checked, and kept for the energy ledger
            a = term.datum.coefficients(t)
            if a is None:
                self.disc.dirichlet_parts[name].add_load(ubar, out)
            else:
                out.maxpy(a, term.vectors)


def _boundary_datum(comm, guard, disc, name: str, key: str, field) -> PointDatum:
    """boundary.NAME.key at the points of boundary part ``name``.  Collective.

    The traction is a function of (x, y, t, nx, ny), the Dirichlet value of (x, y, t).
    """
    points = disc.boundary[name]
    x, y = points.points.T
    arguments = {"x": x, "y": y}
    if key == "traction":
        arguments["nx"], arguments["ny"] = points.normals.T
    return PointDatum(guard, ("boundary", name, key), field, points.points, arguments, comm=comm)


def _coordinates(points: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """A body force's points and arguments (x, y)."""
    x, y = points.T
    return points, {"x": x, "y": y}


def _point_integral(points) -> Integrate:
    """values (2, n) -> S^T (w values) per component on a PointSet."""
    return lambda values, out: points.integrate(values.T, out)


def _point_integrals(points):
    """parts (K, 2, n), outs -> :func:`_point_integral` of each, together (PointSet's
    integrate_many: one MLS pass without a value operator)."""
    return lambda parts, outs: points.integrate_many(np.swapaxes(parts, 1, 2), outs)


def _dirichlet_integral(part) -> Integrate:
    """ubar (2, n) -> L^T (w ubar) of a Dirichlet part."""

    def integrate(values: np.ndarray, out: PETSc.Vec) -> None:
        out.set(0.0)
        part.add_load(np.ascontiguousarray(values.T), out)

    return integrate
