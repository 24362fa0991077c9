"""Static manufactured solutions on the square and the Z: fitted h-convergence rates.

Exact solution (smooth, not in the MLS basis of any degree)::

    u_1 = sin(x) e^y / 2,   u_2 = cos(x + y) / 3,   E = 1, nu = 0.3

solved as one static load step (time.scheme = "static", T = dt = 1); the body force,
the Dirichlet data and the tractions are derived from [exact] by the scene loader.
No contact.  The relative L2 and H1-seminorm errors at h = 1/8, 1/16, 1/32 are fitted
with ``parefg.sweep.fitted_rate`` (``np.polyfit(log h, log e, 1)``) and the slopes asserted
against the rates of the paper's estimate (m + 1 in L2, m in H1) with a margin:
m = 1: L2 >= 1.8, H1 >= 0.9;  m = 2: L2 >= 2.6, H1 >= 1.7.

Collective: every rank loads the scene, builds and solves; the errors are global.
"""

import pytest

from parefg.run import prepare
from parefg.sweep import fitted_rate

EXACT_U = '["sin(x) * exp(y) / 2", "cos(x + y) / 3"]'

# Dirichlet on some parts, Neumann (traction from [exact]) on the others.
BOUNDARIES = {
    "square": {"top": "dirichlet", "left": "dirichlet", "bottom": "neumann", "right": "neumann"},
    "z": {"top": "dirichlet", "bottom": "dirichlet", "sides": "neumann"},
}

H_VALUES = (1 / 8, 1 / 16, 1 / 32)

# MLS degree m -> (minimum L2 rate, minimum H1 rate)
REQUIRED_RATES = {1: (1.8, 0.9), 2: (2.6, 1.7)}


def write_static_scene(path, shape: str) -> str:
    """A static scene TOML on ``shape`` with the exact solution above; returns its path."""
    boundary = "".join(
        f'[boundary.{name}]\ntype = "{kind}"\n\n' for name, kind in BOUNDARIES[shape].items()
    )
    path.write_text(
        f'[domain]\nshape = "{shape}"\n\n'
        "[material]\nE = 1.0\nnu = 0.3\n\n"
        '[time]\nscheme = "static"\nT = 1.0\ndt = 1.0\n\n'
        f"{boundary}"
        f"[exact]\nu = {EXACT_U}\n"
    )
    return str(path)


def static_errors(comm, scene_path: str, overrides: list[str]) -> dict[str, float]:
    """Relative L2 / H1-seminorm errors of the one-step static solution.  Collective."""
    simulation = prepare(comm, scene_path, overrides)
    scene = simulation.scene
    assert scene.n_steps == 1 and scene.scheme == "static"
    state = simulation.step(simulation.start(), 1)
    return simulation.errors(state.u, scene.T)


def fitted_rates(comm, scene_path: str, overrides_of_h) -> tuple[float, float, list]:
    """Slopes of log e_L2 and log e_H1 against log h over H_VALUES.  Collective."""
    errors = [static_errors(comm, scene_path, overrides_of_h(h)) for h in H_VALUES]
    l2_rate = fitted_rate(H_VALUES, [e["l2_rel"] for e in errors])
    h1_rate = fitted_rate(H_VALUES, [e["h1_rel"] for e in errors])
    return l2_rate, h1_rate, errors


@pytest.mark.parametrize("shape", ["square", "z"])
def test_static_rates_degree_1(comm, tmp_path, shape):
    """m = 1 with the defaults: alpha = 1e4 E/h, support 2.0, 3 x 3 Gauss points per cell.

    At these h the Dirichlet penalty is not the limiting error (measured: L2 rates 2.8
    on the square and 2.4 on the Z, H1 1.9 and 1.4).
    """
    scene_path = write_static_scene(tmp_path / f"static_{shape}.toml", shape)

    def overrides(h):
        return [f"discretization.h={h}", "discretization.degree=1"]

    l2_rate, h1_rate, errors = fitted_rates(comm, scene_path, overrides)
    l2_min, h1_min = REQUIRED_RATES[1]
    assert l2_rate >= l2_min, (l2_rate, errors)
    assert h1_rate >= h1_min, (h1_rate, errors)
    assert errors[-1]["h1_rel"] < 5e-3


@pytest.mark.parametrize("shape", ["square", "z"])
def test_static_rates_degree_2(comm, tmp_path, shape):
    """m = 2 with alpha = 1e4 E/h^2 and 8 x 8 Gauss points per cell (support 3.2).

    Why not the defaults, measured on the square and the Z: with alpha = 1e4 E/h the L2
    error flattens at ~5e-6 from h = 1/16 to 1/32 (fitted L2 rate 2.4 on the square)
    whatever the quadrature, a Dirichlet-penalty floor that larger alpha lowers; so alpha
    grows like h^-2 here.  (A fixed huge alpha over-constrains the coarse MLS trace and
    inflates the fitted rates; 1e4 E/h^2 gives rates near the theoretical 3 and 2.)  On
    the Z the default 5 x 5 rule limits the H1 error (rate 1.5); 8 x 8 removes that
    (measured: square L2 3.25, H1 2.38; Z L2 2.84, H1 2.03).
    """
    scene_path = write_static_scene(tmp_path / f"static_{shape}.toml", shape)

    def overrides(h):
        return [
            f"discretization.h={h}",
            "discretization.degree=2",
            "discretization.quadrature=8",
            f"penalty.alpha={1e4 / h**2}",
        ]

    l2_rate, h1_rate, errors = fitted_rates(comm, scene_path, overrides)
    l2_min, h1_min = REQUIRED_RATES[2]
    assert l2_rate >= l2_min, (l2_rate, errors)
    assert h1_rate >= h1_min, (h1_rate, errors)
    assert errors[-1]["h1_rel"] < 1e-3
