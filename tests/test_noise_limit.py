"""The negative-value limit follows each curve's own noise (fitting.data.negative_limit)."""

from __future__ import annotations

import numpy as np
import pytest

from axialmix.analytic import exit_age_closed
from fitting.data import (
    MAX_NEGATIVE_FRACTION,
    NOISE_SIGMAS,
    DataError,
    negative_limit,
    noise_level,
    validated_curve,
)


def _curve(points, noise, seed, tau=7.0, peclet=20.0):
    t = np.linspace(0.0, 6 * tau, points)
    y = np.asarray(exit_age_closed(t, tau, peclet))
    rng = np.random.default_rng(seed)
    return t, y + noise * y.max() * rng.standard_normal(points), y.max()


def test_noise_level_recovers_the_noise_of_a_smooth_curve():
    # 400 samples: the median absolute deviation of 398 second differences has a relative
    # standard error of about 1.36 / sqrt(398) = 7 %; 25 % allowed (3.5 of them).
    for seed in range(5):
        for noise in (0.005, 0.02, 0.05):
            _, y, peak = _curve(400, noise, seed)
            assert noise_level(y) == pytest.approx(noise * peak, rel=0.25)


def test_noise_dip_is_kept_and_a_gross_error_refused():
    t, y, peak = _curve(121, 0.02, 3)
    dipped = y.copy()
    dipped[3] = -0.052 * peak  # 2.6 sigma of 2 % noise: noise
    curve = validated_curve("s.csv", np.arange(2, 123), t, dipped, name="c3", normalise=False)
    assert curve.value[3] == dipped[3]
    wrong = y.copy()
    wrong[3] = -0.30 * peak  # 15 sigma: not noise
    with pytest.raises(DataError) as error:
        validated_curve("s.csv", np.arange(2, 123), t, wrong, name="c3", normalise=False)
    message = str(error.value)
    assert "row 5" in message and "'c3'" in message and "negative value" in message
    assert "\n" not in message


def test_limit_is_capped_whatever_the_noise_estimate():
    # Nine samples of a sharp, wiggly peak: its curvature reads as noise, the cap holds.
    y = np.array([0.0, 0.4, 0.1, 1.0, 0.2, 0.7, 0.0, 0.3, 0.0])
    limit, sigma = negative_limit(y)
    assert NOISE_SIGMAS * sigma > MAX_NEGATIVE_FRACTION
    assert limit == pytest.approx(-MAX_NEGATIVE_FRACTION * 1.0)


@pytest.mark.study
def test_false_refusal_rate_on_1000_noisy_curves():
    # 1,000 curves of 41 to 801 samples, additive Gaussian noise of 0.5 % to 4 % of the peak:
    # the number refused by the noise-based limit and by the old fixed 5 % of the peak.
    rng = np.random.default_rng(20261201)
    refused = fixed = 0
    for k in range(1000):
        points = int(rng.choice([41, 81, 121, 201, 401, 801]))
        noise = float(rng.uniform(0.005, 0.04))
        t, y, peak = _curve(points, noise, k, tau=float(rng.uniform(3, 30)),
                            peclet=float(rng.uniform(5, 80)))
        fixed += bool(np.any(y < -0.05 * peak))
        try:
            validated_curve("s.csv", np.arange(points), t, y, name=f"c{k}", normalise=False,
                            on_truncated="ignore")
        except DataError:
            refused += 1
    print(f"\n1000 noisy curves: refused by the noise-based limit ({NOISE_SIGMAS:g} sigma, "
          f"5-25 % of the peak) {refused} ({refused / 10:.1f} %), by a fixed 5 % of the peak "
          f"{fixed} ({fixed / 10:.1f} %)")
    assert refused == 0
