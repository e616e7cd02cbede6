"""The seed-matched time rule and the inverse fit of Table 6 (benchmarks/smpm_seed_time.py;
docs/mpm_scenes.md, "Seed conventions: at which time do the seed's tables fit?"), on
synthetic data: fast, no solver run."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))   # benchmarks/ is not installed
from benchmarks.smpm_seed_time import (first_crossing, fit_state,  # noqa: E402
                                       flow_stress_moments, seed_matched_time)


def _ramps(times, onsets, slopes):
    """Plastic strain that starts growing at each probe's onset, linearly."""
    return np.maximum(0.0, (times[:, None] - onsets[None, :]) * slopes[None, :])


def test_matched_time_is_where_every_probe_reaches_its_target_together():
    times = np.arange(0.0, 100.5, 0.5)
    onsets, slopes = np.array([6.0, 7.0, 7.5, 8.0]), np.array([0.01, 0.015, 0.02, 0.012])
    t_true = 10.0
    targets = (t_true - onsets) * slopes
    i = seed_matched_time(times, _ramps(times, onsets, slopes), targets)
    assert times[i] == t_true


def test_matched_time_ignores_noise_in_later_plateaus_and_prefers_the_earliest_tie():
    times = np.arange(0.0, 50.5, 0.5)
    eps = _ramps(times, np.array([5.0, 5.0]), np.array([0.01, 0.01]))
    eps = np.minimum(eps, 0.02)        # reaches 0.02 at 7 us and stays there
    i = seed_matched_time(times, eps, np.array([0.02, 0.02]))
    assert times[i] == 7.0


def test_matched_time_balances_probes_that_disagree():
    times = np.arange(0.0, 20.5, 0.5)
    eps = np.column_stack([0.01 * times, 0.01 * times])
    # targets reached at 4 and 6 us: equal relative weights put the optimum in between,
    # nearer the probe with the larger target (its relative misfit grows more slowly)
    i = seed_matched_time(times, eps, np.array([0.04, 0.06]))
    assert 4.0 < times[i] < 6.0


def test_matched_time_rejects_bad_shapes_and_targets():
    times = np.arange(5.0)
    with pytest.raises(ValueError, match="eps_p must be"):
        seed_matched_time(times, np.zeros((5, 3)), np.ones(2))
    with pytest.raises(ValueError, match="positive"):
        seed_matched_time(times, np.zeros((5, 2)), np.array([0.01, 0.0]))


def test_first_crossing_interpolates_and_reports_never():
    times = np.array([0.0, 1.0, 2.0, 3.0])
    series = np.array([0.0, 0.0, 0.02, 0.04])
    # bound: a few roundings (eps 2.2e-16) of one linear interpolation
    assert first_crossing(times, series, 0.01) == pytest.approx(1.5, rel=1e-12)
    assert np.isnan(first_crossing(times, series, 0.05))


def test_moments_agree_with_a_monte_carlo_of_the_closed_form():
    rng = np.random.default_rng(7)
    n = 400_000
    cv, lp, lr = 0.15, np.log(0.03), -4.3
    A, B, C, nn = (rng.normal(m, cv * m, n) for m in (0.792, 0.510, 0.014, 0.26))
    s = (A + B * np.exp(nn * lp)) * (1.0 + C * lr)
    mean, var = flow_stress_moments(lp, lr, cv)
    # 5 sampling standard errors: s/sqrt(n) for the mean, s^2 sqrt(2/(n-1)) x kurtosis margin
    assert mean == pytest.approx(s.mean(), abs=5 * s.std() / np.sqrt(n))
    assert var == pytest.approx(s.var(), rel=5 * np.sqrt(3.0 / n))


def test_inverse_fit_recovers_a_known_state():
    lp, lr = np.log(0.025), -4.5
    m10, v10 = flow_stress_moments(lp, lr, 0.10)
    m15, v15 = flow_stress_moments(lp, lr, 0.15)
    fit = fit_state("X", m10, m15, v10, v15)
    # exact data: the least-squares optimum is the state itself, up to the solver's tolerance
    assert fit.eps_p == pytest.approx(0.025, rel=1e-4)
    assert fit.log_rate_star == pytest.approx(-4.5, abs=1e-4)
    assert max(abs(r) for r in fit.residuals_in_stderr) < 1e-3
