"""Hertz line contact: an elastic half-disk pressed on the rigid plane y = 0 (plane strain).

A verification case against a closed form from the literature (Johnson, *Contact
Mechanics*, 1985, sec. 4.2), not a manufactured solution: an elastic cylinder of
radius R pressed on a rigid flat by the load P per unit thickness, frictionless, touches
it over |x| <= a with the elliptic pressure

    a = sqrt(4 P R / (pi E*)),   p(x) = p0 sqrt(1 - x^2 / a^2),   p0 = 2 P / (pi a),

E* = E / (1 - nu^2) (the rigid flat has no compliance).  Hertz's half-space idealization
holds for a << R; its error is O(a / R).

The scene (:func:`hertz_scene`): ``meshes/half_disk.geo`` (R = 1, centre (0, 1): the
curved bottom touches y = 0 at the origin, nodes graded to h/10 within 0.15 of it), a
static load step pushing the flat top y = 1 down by ``delta`` (Nitsche, the top
clamped: u = (0, -delta)), frictionless contact (penalty or Nitsche) on the arc within
30 degrees of the bottom.  The load P is not prescribed but measured: the vertical resultant of the
contact pressure, checked against the stress resultant through the body
(:func:`stress_resultant`).  The Hertz values are those of the measured P.

Two scene choices matter for penalty contact on a curved boundary:

* The Gamma_C points lie on the chords of the mesh's boundary segments, up to
  L^2 / (8 R) inside the arc (1.25e-5 at L = 0.01).  The default penalty's penetration
  (p / alpha ~ 5e-6) is below that, so a gap measured from the chord lets only the
  segments' ends touch (measured: peak pressure 12x Hertz's p0, most points open).  The
  gap is therefore that of the true arc (the point projected radially onto the circle),
  measured to the plane along the body's normal as SPEC 1 defines it: s = y_arc / cos
  theta = r / (1 - y) - 1, r = |x - (0, 1)|.
* The contact penalty scales with the local node spacing h_c = h / 10 there:
  alpha_C = ``alpha_factor`` E / h_c.  The default alpha = 1e4 E / h amplifies the MLS
  trace's pointwise error into a pressure oscillating between 0 and 7 p0 along Gamma_C;
  at 10 E / h_c it is smooth to a few percent (see scripts/verify/hertz_study.py).

parefg imposes u . nu <= s with the body's normal nu, Hertz -u_y <= x^2 / (2R): the
difference narrows the contact by 1.8 % here (:func:`normal_projection_half_width`, the
closed form the scene converges to).

Not collective, except :func:`contact_points`, :func:`stress_resultant` and
:func:`measure`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mpi4py import MPI

from parefg.discretization.dirichlet import NITSCHE_CONTACT_METHODS

#: the mesh source (R = 1); nodes graded to h * CONTACT_REFINEMENT near the origin
HALF_DISK_GEO = Path(__file__).resolve().parents[2] / "meshes" / "half_disk.geo"
RADIUS = 1.0
CONTACT_REFINEMENT = 0.1  # half_disk.geo's SizeMin = h / 10
E, NU = 1.0, 0.3


#: the gap from the true arc (the point projected radially onto the circle) ...
ARC_GAP = "sqrt(x**2 + (1 - y)**2) / (1 - y) - 1"
#: ... and from the chord the point lies on (only for showing why not: module docstring)
CHORD_GAP = "y / (1 - y)"


def hertz_scene(
    h: float,
    delta: float,
    contact: float | str = 10.0,
    degree: int = 2,
    nu: float = NU,
    gap: str = ARC_GAP,
) -> str:
    """The TOML text of the Hertz scene at spacing h and top displacement delta.

    ``contact``: a number c is penalty contact with alpha_C = c E / h_c; ``"penalty"`` the
    penalty at parefg's default alpha (1e4 E / h); ``"nitsche"`` Nitsche contact (its
    gamma from the trace-inverse estimate), or another of NITSCHE_CONTACT_METHODS.
    """
    if contact in NITSCHE_CONTACT_METHODS:
        method, penalty = contact, ""
    elif contact == "penalty":
        method, penalty = "penalty", ""
    else:
        alpha = float(contact) * E / (CONTACT_REFINEMENT * h)
        method, penalty = "penalty", f"[penalty]\nalpha_contact = {alpha!r}\n"
    return f"""
name = "hertz"
[domain]
shape = "geo"
file = "{HALF_DISK_GEO}"
parts = ["contact", "free", "top"]
[discretization]
h = {h!r}
degree = {degree}
[material]
E = {E!r}
nu = {nu!r}
[time]
scheme = "static"
T = 1.0
dt = 1.0
{penalty}[boundary.contact]
type = "contact"
method = "{method}"
gap = "{gap}"
[boundary.top]
type = "dirichlet"
value = [0, "-{delta!r} * t"]
[output]
every = 0
"""


def hertz_closed_form(load: float, e_star: float, radius: float = RADIUS) -> tuple[float, float]:
    """(a, p0) of the Hertz line contact under the load per unit thickness ``load``."""
    a = np.sqrt(4.0 * load * radius / (np.pi * e_star))
    return float(a), float(2.0 * load / (np.pi * a))


def normal_projection_half_width(
    load: float, lam: float, mu: float, radius: float = RADIUS
) -> tuple[float, float]:
    """(a, p0) of the contact parefg solves, to first order in p0 / E: Hertz's with the
    normal of the body instead of the plane's.

    parefg's Signorini condition (SPEC 1) is u . nu <= s with nu the body's outward normal
    nu = (x / R, -cos theta) on the arc; Hertz's is -u_y <= x^2 / (2R).  The difference is
    u_x x / R: the surface inside the contact moves towards its centre,
    u_x(x) = -k [int_-a^x p - int_x^a p], k = (1 - 2 nu)(1 + nu) / (2 E) (Johnson eq. 2.25b,
    half-plane under a normal pressure), which adds k F(x) x / R to the gap,
    F(x) = 2 int_0^x p, and narrows the contact.  Here a solves the bounded-edge condition
    of a 2D frictionless punch (Johnson sec. 2.8), P = E*/2 int_-a^a x g'(x) / sqrt(a^2 - x^2)
    dx, with g(x) = x^2 / (2R) + k F(x) x / R and F of the elliptic pressure of that a and P
    (first order); p0 = 2 P / (pi a).  Measured (nu = 0.3, P = 8.45e-3): a 1.78 % below
    Hertz's a, p0 1.82 % above, what the scene converges to (scripts/verify/hertz_study.py).
    The correction scales with (1 - 2 nu)(1 + nu) p0 / E, i.e. with a / R.  Terms of
    O((a/R)^2) are left out (circle against parabola, the gap along the normal y/cos theta
    against y cos theta: +0.5 % in a measured, the finite body): ~0.5 % at a/R = 0.1.
    """
    from scipy.optimize import brentq

    e_star = 4.0 * mu * (lam + mu) / (lam + 2.0 * mu)
    nu = lam / (2.0 * (lam + mu))
    young = 2.0 * mu * (1.0 + nu)
    k = (1.0 - 2.0 * nu) * (1.0 + nu) / (2.0 * young)
    theta = np.linspace(-0.5 * np.pi, 0.5 * np.pi, 2001)  # x = a sin(theta)
    weights = np.full(theta.size, theta[1] - theta[0])
    weights[[0, -1]] *= 0.5  # trapezoidal rule: the integrand is smooth in theta

    def load_of(a: float) -> float:
        p0 = 2.0 * load / (np.pi * a)
        x = a * np.sin(theta)
        ratio = np.sin(theta)
        force = p0 * (x * np.cos(theta) + a * np.arcsin(ratio))  # F(x) = 2 int_0^x p
        pressure = p0 * np.cos(theta)
        slope = x / radius + k / radius * (force + 2.0 * x * pressure)  # g'(x)
        # dx / sqrt(a^2 - x^2) = d theta
        return 0.5 * e_star * float(np.dot(weights, x * slope))

    a_hertz, _ = hertz_closed_form(load, e_star, radius)
    a = brentq(lambda a: load_of(a) - load, 0.5 * a_hertz, 1.5 * a_hertz, xtol=1e-14)
    return float(a), float(2.0 * load / (np.pi * a))


@dataclass
class HertzMeasure:
    """What :func:`measure` reads off a solved Hertz scene (R = 1 units)."""

    load: float  # P: vertical resultant of the contact pressure, sum w p (-nu_y)
    load_x: float  # horizontal resultant (0 by symmetry)
    load_stress: float  # P from the stress through the body (stress_resultant)
    a_hertz: float  # closed form at the measured P
    p0_hertz: float
    a_normal: float  # Hertz with the body's normal (normal_projection_half_width)
    p0_normal: float
    a_moment: float  # 2 sqrt(int p x^2 / int p): a for an elliptic p, any p0
    a_fit: float  # least-squares fit of p0 sqrt(1 - x^2/a^2)_+ to the point pressures
    p0_fit: float
    p_max: float  # largest point pressure
    a_edge: float  # largest |x| of a closed point
    n_closed: int


def contact_points(sim, u) -> tuple[np.ndarray, ...]:
    """(x (n, 2), outward normals (n, 2), weights (n,), pressure (n,), closed (n,)) of all
    Gamma_C points, on every rank: the traction the body feels (ContactFrame.tractions) and
    where the law acts.  Collective."""
    law = sim.law
    point_pressure = law.pressure(law.kinematics(u)[0])
    pressure = law.tractions(point_pressure, np.zeros_like(point_pressure))[0]
    local = (law.points, law.normals, law.weights, pressure, point_pressure > 0)
    gathered = sim.comm.allgather(local)
    return tuple(np.concatenate([part[k] for part in gathered]) for k in range(5))  # type: ignore[return-value]


def stress_resultant(sim, u, band: tuple[float, float] = (0.3, 0.7)) -> float:
    """The vertical force through the body, from sigma_yy of u_h.  Collective.

    Equilibrium of the body below any cut y = c: int_cut sigma_yy dx = -P.  Averaged over
    the cuts of ``band`` with the smooth weight psi'(y) (psi = 1 below the band, 0 above,
    a cosine ramp between), P = int_Omega sigma_yy psi'(y): the virtual work of the
    stress in the field v = (0, psi(y)), which is not in the MLS space, so this is not the
    discrete equilibrium identity that the contact resultant satisfies with the Dirichlet
    reaction by construction.  psi' is continuous, so the cells' Gauss rules integrate it
    accurately although the band cuts the cells.
    """
    lam, mu = sim.scene.material.lam, sim.scene.material.mu
    domain = sim.disc.domain
    grad = domain.evaluate_gradient(u)  # (n_q, 2, 2), [q, i, j] = du_i/dx_j
    sigma_yy = lam * (grad[:, 0, 0] + grad[:, 1, 1]) + 2.0 * mu * grad[:, 1, 1]
    y0, y1 = band
    points, weights = domain.restore_points()  # computed again if the run released them
    y = points[:, 1]
    inside = (y > y0) & (y < y1)
    dpsi = np.where(inside, -0.5 * np.pi / (y1 - y0) * np.sin(np.pi * (y - y0) / (y1 - y0)), 0.0)
    local = float(np.dot(weights, sigma_yy * dpsi))
    return float(sim.comm.allreduce(local, op=MPI.SUM))


def measure(sim, u) -> HertzMeasure:
    """Contact resultants, half-widths and peak pressures of the solved state u.  Collective."""
    from scipy.optimize import least_squares

    x, normals, weights, pressure, closed = contact_points(sim, u)
    # the vertical traction per unit x: p ds (-nu_y) = p dx on the curve
    wy = weights * -normals[:, 1]
    load = float(np.dot(wy, pressure))
    load_x = float(np.dot(weights * -normals[:, 0], pressure))
    lam, mu = sim.scene.material.lam, sim.scene.material.mu
    e_star = 4.0 * mu * (lam + mu) / (lam + 2.0 * mu)  # E / (1 - nu^2)
    a_hertz, p0_hertz = hertz_closed_form(load, e_star)
    a_normal, p0_normal = normal_projection_half_width(load, lam, mu)
    xs = x[:, 0]
    a_moment = 2.0 * float(np.sqrt(np.dot(wy, pressure * xs**2) / load))

    def residual(params):
        p0, a = params
        return np.sqrt(wy) * (pressure - p0 * np.sqrt(np.maximum(1.0 - (xs / a) ** 2, 0.0)))

    fit = least_squares(residual, [p0_hertz, a_hertz], x_scale=[p0_hertz, a_hertz])
    return HertzMeasure(
        load=load,
        load_x=load_x,
        load_stress=stress_resultant(sim, u),
        a_hertz=a_hertz,
        p0_hertz=p0_hertz,
        a_normal=a_normal,
        p0_normal=p0_normal,
        a_moment=a_moment,
        a_fit=float(fit.x[1]),
        p0_fit=float(fit.x[0]),
        p_max=float(pressure.max()),
        a_edge=float(np.abs(xs[closed]).max()) if closed.any() else 0.0,
        n_closed=int(closed.sum()),
    )
