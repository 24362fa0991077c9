"""Scene texts shared by the tests and the benchmarks: verification cases, not built-in scenes.

Each is the TOML of a scene with a closed-form or manufactured solution that a test
asserts and a benchmark measures (tests/timestepping/test_schemes.py and
scripts/bench/bench_schemes.py; tests/mechanics/test_coulomb.py and
scripts/bench/bench_coulomb.py).  Write one to a file and load it with
:func:`parefg.scene.loader.load_scene`.  Not collective.
"""

# -- at rest: time-independent exact solutions with u != 0 -------------------------------
#: clamped (penalty) at y = 1, tractions elsewhere
AT_REST = """
[domain]
shape = "square"
[discretization]
h = 0.125
degree = 2
[time]
T = 0.5
dt = 0.05
[boundary.top]
type = "dirichlet"
[boundary.bottom]
type = "neumann"
[boundary.left]
type = "neumann"
[boundary.right]
type = "neumann"
[exact]
u = ["0.1 * (1 + x) * exp(y)", "-0.1 * y * exp(x)"]
"""

#: a compression resting on the obstacle at y = 0 (pressure 0.04, no tangential
#: traction), clamped at y = 1
AT_REST_ON_OBSTACLE = AT_REST.replace(
    '[boundary.bottom]\ntype = "neumann"', '[boundary.bottom]\ntype = "contact"'
).replace('["0.1 * (1 + x) * exp(y)", "-0.1 * y * exp(x)"]', '["0.02 * x", "-0.05 * y"]')

# -- Coulomb friction ------------------------------------------------------------------
#: the sliding block's initial speed, Coulomb coefficient and pressing acceleration
SLIDE_V0, SLIDE_MU, SLIDE_G = 0.5, 0.3, 1.0

#: an elastic 1 x 0.25 block on the obstacle at y = 0, pressed by f = (0, -G) and thrown
#: along it with v = (V0, 0): the mean velocity decelerates at -MU G while it slides and
#: stops at V0 / (MU G).  gamma = 0.7 damps the elastic ringing of the block once it stops
#: (the shear it carried while decelerating is released at once); alpha_contact = 10 E/h
#: keeps the contact pressure smooth along the MLS trace (1e4 E/h makes it oscillate,
#: open patches included).
COULOMB_SLIDE = f"""
name = "slide"
[domain]
shape = "rectangle"
size = [1.0, 0.25]
[discretization]
h = 0.125
degree = 1
[material]
E = 1000.0
nu = 0.3
rho = 1.0
[time]
T = 2.2
dt = 0.02
beta = 0.36
gamma = 0.7
[penalty]
alpha_contact = 1e4
[boundary.bottom]
type = "contact"
method = "penalty"
friction_law = "coulomb"
friction_coefficient = {SLIDE_MU}
[initial]
v = [{SLIDE_V0}, 0.0]
[loads]
f = [0.0, {-SLIDE_G}]
"""

#: the unit square sliding at the Coulomb bound mu_f = 0.3 on y = 0 (lam = mu = 1):
#: u_1 = (1 - cos t) [(1 + x) + y (0.9 e^x - 0.3)], u_2 = -(1 - cos t) y e^x
COULOMB_MMS = """
name = "coulomb_mms"
[domain]
shape = "square"
[discretization]
h = 0.125
degree = 1
[material]
lam = 1.0
mu = 1.0
rho = 1.0
[time]
T = 1.0
dt = 0.0125
[boundary.bottom]
type = "contact"
friction_law = "coulomb"
friction_coefficient = 0.3
[boundary.top]
type = "dirichlet"
method = "penalty"  # the clamp of test_coulomb's measured 1 % agreement (issue 12: explicit)
[boundary.left]
type = "neumann"
[boundary.right]
type = "neumann"
[exact]
u = ["(1 - cos(t)) * ((1 + x) + y * (0.9 * exp(x) - 0.3))", "-(1 - cos(t)) * y * exp(x)"]
"""
