"""The one log-log rate fit (``parefg.sweep.fitted_rate``) used by the sweep, the
convergence tables and the verification tests.

Expected values are exact: for e = C x^p the least-squares slope of log e against log x
is p whatever C and the points.  A failed case (error nan, 0 or negative) must make the
fit nan rather than be dropped, so that a test asserting a rate cannot pass on the
remaining points; only the sweep's table, where scenes without [exact] have no error,
skips the cases without one.
"""

import numpy as np
import pytest

from parefg.sweep import fitted_rate, rate_table


@pytest.mark.parametrize("order", [0.5, 1.0, 2.0, 3.25])
def test_exact_power_law_gives_its_exponent(order):
    h = np.array([0.25, 0.125, 0.0625, 0.03125, 0.02])
    assert fitted_rate(h, 7.0 * h**order) == pytest.approx(order, rel=1e-12)


def test_two_points_give_the_slope_between_them():
    assert fitted_rate([0.1, 0.05], [4e-3, 1e-3]) == pytest.approx(2.0, rel=1e-12)


@pytest.mark.parametrize("bad", [np.nan, np.inf, 0.0, -1e-3])
def test_a_failed_case_makes_the_fit_nan(bad):
    h = [0.5, 0.25, 0.125]
    assert np.isnan(fitted_rate(h, [bad, 1e-2, 2.5e-3]))


@pytest.mark.parametrize("x", [[0.1], [0.1, 0.1, 0.1]])
def test_fewer_than_two_distinct_sizes_give_nan(x):
    assert np.isnan(fitted_rate(x, [1e-2] * len(x)))


def test_sweep_table_fits_the_cases_that_have_an_error():
    """Three dt with errors 4e-2, 1e-2 (order 2) and one case without an error."""
    rows = [
        {"degree": 1, "h": 0.1, "dt": dt, "n_dofs": 8, "l2_rel": l2, "h1_rel": l2, "time": 0.0}
        for dt, l2 in [(0.2, 4e-2), (0.1, 1e-2), (0.05, np.nan)]
    ]
    for row in rows:
        row["newton"] = 1
    assert "rate in dt (all): L2 2.00, H1 2.00" in rate_table(rows, ["time.dt"])
