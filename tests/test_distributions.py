"""The fit report's distribution functions against scipy.special (an independent
implementation: Cephes and Boost, where ours are series, continued fractions and Newton)."""

import math

import numpy as np
import pytest
from scipy import special

from fitting.distributions import chi_square_survival, log_factorials, t_quantile
from fitting.residuals import runs_distribution

DOFS = [0.3, 0.5, 1, 1.5, 2, 3, 5, 7.3, 10, 29.5, 30, 31, 100, 1e3, 1e4, 99_999, 1e5, 1e6, 1e9]


@pytest.mark.parametrize("dof", DOFS)
def test_t_quantiles_match_scipy(dof):
    for probability in (0.5, 0.6, 0.9, 0.975, 0.995, 0.9999):
        ours = t_quantile(dof, probability)
        theirs = special.stdtrit(dof, probability)
        # Measured 2.1e-12 at worst (dof 99999, p 0.6: the last dof before the expansion).
        assert ours == pytest.approx(theirs, rel=1e-11, abs=1e-300), probability


def test_t_quantile_limits():
    assert t_quantile(math.inf) == pytest.approx(special.ndtri(0.975), rel=1e-14)
    assert math.isnan(t_quantile(0.0)) and math.isnan(t_quantile(-1.0))
    assert math.isnan(t_quantile(math.nan))
    with pytest.raises(ValueError, match="probability"):
        t_quantile(3.0, 0.4)


@pytest.mark.parametrize("dof", [0.5, 1, 2, 3, 5, 10, 33, 59, 61, 100, 1e3, 1e4, 1e5, 1e6, 1e7])
def test_chi_square_survival_matches_scipy(dof):
    for ratio in (0.0, 1e-3, 0.1, 0.5, 0.9, 0.99, 1.0, 1.01, 1.1, 2.0, 5.0, 20.0):
        x = ratio * dof
        theirs = special.gammaincc(0.5 * dof, 0.5 * x)
        if theirs < 1e-250:
            continue
        # Measured 1.5e-12 at worst (dof 1e7, x 1.01e7, where Q is 2.5e-110).
        assert chi_square_survival(x, dof) == pytest.approx(theirs, rel=1e-11), x


def test_chi_square_survival_rejects_nonsense():
    with pytest.raises(ValueError, match="dof"):
        chi_square_survival(1.0, 0.0)
    assert math.isnan(chi_square_survival(math.nan, 3.0))
    assert chi_square_survival(math.inf, 3.0) == 0.0


def test_log_factorials_match_gammaln():
    table = log_factorials(3000)
    assert table[0] == 0.0 and table[1] == 0.0
    np.testing.assert_allclose(table, special.gammaln(np.arange(1, 3002)), rtol=1e-14)


@pytest.mark.parametrize(
    ("n_positive", "n_negative"), [(1, 1), (1, 7), (5, 5), (13, 40), (200, 190)]
)
def test_runs_distribution_is_a_distribution_with_the_known_mean(n_positive, n_negative):
    runs, probability = runs_distribution(n_positive, n_negative)
    assert np.sum(probability) == pytest.approx(1.0, rel=1e-12)
    total = n_positive + n_negative
    # E[runs] = 1 + 2 n1 n2 / (n1 + n2) for a random order (Wald and Wolfowitz 1940).
    assert np.sum(runs * probability) == pytest.approx(
        1.0 + 2.0 * n_positive * n_negative / total, rel=1e-12)


def test_t_quantile_of_a_tiny_number_of_degrees_of_freedom():
    """Below 0.01 degrees of freedom the quantile comes from the tail's leading term (an
    effective dof that small arises from relative-error weights on additive noise); it
    agrees with SciPy just below the switch (further down SciPy's own quantile saturates near
    1e152) and grows without bound as dof falls."""
    from scipy import stats

    for probability in (0.6, 0.975):
        expected = stats.t.ppf(probability, 0.0099)
        assert t_quantile(0.0099, probability) == pytest.approx(expected, rel=1e-9)
    assert t_quantile(1e-3) == math.inf and t_quantile(1.19e-8) == math.inf
    values = [t_quantile(d) for d in (0.05, 0.02, 0.011, 0.0099, 0.005)]
    assert all(a < b for a, b in zip(values, values[1:], strict=False))
