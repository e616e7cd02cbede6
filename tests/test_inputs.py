"""Random inputs: moments against scipy.stats' exact values, sampling, validation, correlation.

Every number is checked against an independent reference: scipy.stats frozen distributions
built here from the documented parameter maps (docs/inputs.md), closed-form limits, or
sample statistics with a tolerance of a few standard errors.
"""

from __future__ import annotations

import math

import chaospy
import numpy as np
import pytest
from scipy import optimize, special, stats

from uqflow.errors import StudyError
from uqflow.inputs import DISTRIBUTIONS, InputSpace, RandomInput, check_correlation, \
    make_distribution
from uqflow.sampling import unit_hypercube

N_SAMPLES = 20_000
SQRT3 = math.sqrt(3.0)


# --------------------------------------------------------------------------------------------
# Independent references (scipy.stats), from the parameter maps stated in docs/inputs.md
# --------------------------------------------------------------------------------------------

def _weibull_shape(cv):
    """Shape k with sqrt(G(1+2/k)/G(1+1/k)^2 - 1) = cv (moderate cv: plain gamma is exact)."""
    def f(k):
        return math.sqrt(special.gamma(1 + 2 / k) / special.gamma(1 + 1 / k) ** 2 - 1) - cv
    # Solved to float64 resolution: brentq's own floor is 4 eps |k| (~1e-15 relative).
    return optimize.brentq(f, 0.5, 50.0, xtol=1e-15, rtol=1e-15)


def _truncnorm_parent(mean, std, lo, hi):
    """(mu, sigma) of the parent normal whose truncation to [lo, hi] has this mean and std."""
    def f(z):
        mu, sigma = z[0], math.exp(z[1])
        m, v = stats.truncnorm.stats((lo - mu) / sigma, (hi - mu) / sigma, loc=mu, scale=sigma,
                                     moments="mv")
        return [(m - mean) / std, (math.sqrt(v) - std) / std]
    z = optimize.fsolve(f, [mean, math.log(std)], xtol=1e-13)
    assert max(abs(r) for r in f(z)) < 1e-11
    return z[0], math.exp(z[1])


def _ref_normal(p):
    std = p["std"] if "std" in p else p["cv"] * abs(p["mean"])
    return stats.norm(p["mean"], std)


def _ref_lognormal(p):
    if "mu" in p:
        return stats.lognorm(p["sigma"], scale=math.exp(p["mu"]))
    cv = p["cv"] if "cv" in p else p["std"] / p["mean"]
    s2 = math.log(1 + cv * cv)
    return stats.lognorm(math.sqrt(s2), scale=math.exp(math.log(p["mean"]) - s2 / 2))


def _ref_uniform(p):
    if "lower" in p:
        return stats.uniform(p["lower"], p["upper"] - p["lower"])
    std = p["std"] if "std" in p else p["cv"] * abs(p["mean"])
    return stats.uniform(p["mean"] - SQRT3 * std, 2 * SQRT3 * std)


def _ref_weibull(p):
    lo = p.get("lower", 0.0)
    if "shape" in p:
        return stats.weibull_min(p["shape"], loc=lo, scale=p["scale"])
    std = p["std"] if "std" in p else p["cv"] * abs(p["mean"])
    k = _weibull_shape(std / (p["mean"] - lo))
    return stats.weibull_min(k, loc=lo, scale=(p["mean"] - lo) / special.gamma(1 + 1 / k))


def _ref_beta(p):
    lo, hi = p.get("lower", 0.0), p.get("upper", 1.0)
    if "alpha" in p:
        return stats.beta(p["alpha"], p["beta"], loc=lo, scale=hi - lo)
    std = p["std"] if "std" in p else p["cv"] * abs(p["mean"])
    m, s = (p["mean"] - lo) / (hi - lo), std / (hi - lo)
    nu = m * (1 - m) / s**2 - 1
    return stats.beta(m * nu, (1 - m) * nu, loc=lo, scale=hi - lo)


def _ref_truncnormal(p):
    lo, hi = p.get("lower", -math.inf), p.get("upper", math.inf)
    if "mu" in p:
        mu, sigma = p["mu"], p["sigma"]
    else:
        std = p["std"] if "std" in p else p["cv"] * abs(p["mean"])
        mu, sigma = _truncnorm_parent(p["mean"], std, lo, hi)
    return stats.truncnorm((lo - mu) / sigma, (hi - mu) / sigma, loc=mu, scale=sigma)


REFERENCE = {"normal": _ref_normal, "lognormal": _ref_lognormal, "uniform": _ref_uniform,
             "weibull": _ref_weibull, "beta": _ref_beta, "truncnormal": _ref_truncnormal}

# (id, distribution, parameters): every distribution in its moment form (mean + cv or std,
# cv = 0.3 throughout) and in its native form.
CASES = [
    ("normal-cv", "normal", {"mean": 2.0, "cv": 0.3}),
    ("normal-negative-mean", "normal", {"mean": -2.0, "cv": 0.3}),
    ("normal-std", "normal", {"mean": 2.0, "std": 0.6}),
    ("truncnormal-cv-lower", "truncnormal", {"mean": 1.0, "cv": 0.3, "lower": 0.5}),
    ("truncnormal-cv-both", "truncnormal", {"mean": 1.0, "cv": 0.3, "lower": 0.4, "upper": 1.8}),
    ("truncnormal-native", "truncnormal", {"mu": 1.0, "sigma": 0.3, "lower": 0.8, "upper": 1.5}),
    ("lognormal-cv", "lognormal", {"mean": 2.0, "cv": 0.3}),
    ("lognormal-native", "lognormal", {"mu": 0.1, "sigma": 0.4}),
    ("uniform-cv", "uniform", {"mean": 2.0, "cv": 0.3}),
    ("uniform-native", "uniform", {"lower": -1.0, "upper": 3.0}),
    ("weibull-cv", "weibull", {"mean": 2.0, "cv": 0.3}),
    ("weibull-std-shifted", "weibull", {"mean": 2.0, "std": 0.3, "lower": 1.0}),
    ("weibull-native", "weibull", {"shape": 2.0, "scale": 1.5, "lower": 0.5}),
    ("beta-cv", "beta", {"mean": 0.3, "cv": 0.3}),
    ("beta-std-interval", "beta", {"mean": 1.6, "std": 0.3, "lower": 1.0, "upper": 3.0}),
    ("beta-native", "beta", {"alpha": 2.0, "beta": 5.0, "lower": 1.0, "upper": 3.0}),
]
CASE_IDS = [c[0] for c in CASES]


def _input(kind, params, name="x", units="Pa"):
    return RandomInput.from_spec({"name": name, "distribution": kind, "units": units, **params})


def _exact(ref):
    mean, var, skew, exkurt = (float(v) for v in ref.stats(moments="mvsk"))
    return mean, math.sqrt(var), skew, exkurt + 3.0


def _sample(inputs, rule, n=N_SAMPLES, seed=2024, correlation=None):
    space = InputSpace(inputs, correlation)
    u = unit_hypercube(rule, n, len(space), np.random.SeedSequence(seed))
    return space.from_unit_hypercube(u)


def test_every_distribution_is_covered():
    assert {c[1] for c in CASES} == set(DISTRIBUTIONS)


@pytest.mark.parametrize("case_id, kind, params", CASES, ids=CASE_IDS)
def test_moments_match_scipy(case_id, kind, params):
    """Reported mean, std, skewness and kurtosis equal scipy.stats' exact values (rtol 1e-8)."""
    inp = _input(kind, params)
    mean, std, skew, kurt = _exact(REFERENCE[kind](params))
    assert inp.kind == kind and inp.units == "Pa"
    # Bound: the moment-form solves stop at a residual of 1e-10 std (truncnormal, in
    # uqflow/inputs.py), which the moments' O(10..100) condition in (mu, sigma) turns into
    # <= 1e-8; closed forms and scipy agree to ~1e-14.
    assert inp.mean == pytest.approx(mean, rel=1e-8)
    assert inp.std == pytest.approx(std, rel=1e-8)
    assert inp.variance == pytest.approx(std**2, rel=1e-8)
    # Same bound; abs 1e-10: a symmetric case's skewness of 0 carries the 1e-10 residual.
    assert inp.skewness == pytest.approx(skew, rel=1e-8, abs=1e-10)
    assert inp.kurtosis == pytest.approx(kurt, rel=1e-8)
    # Same bound (1e-10 residual × O(100) condition), in units of std^3 and std^4.
    assert inp.third_central_moment == pytest.approx(skew * std**3, rel=1e-8, abs=1e-10 * std**3)
    assert inp.fourth_central_moment == pytest.approx(kurt * std**4, rel=1e-8)
    assert inp.cv == pytest.approx(std / abs(mean), rel=1e-8)   # = std's and mean's bound
    if "mean" in params:  # the moment form reproduces what was asked for
        # Bound: the solve's residual 1e-10 std, with std/|mean| <= 0.3 here.
        assert inp.mean == pytest.approx(params["mean"], rel=1e-10)
        asked = params.get("std", params.get("cv", 0) * abs(params["mean"]))
        assert inp.std == pytest.approx(asked, rel=1e-9)   # residual 1e-10 of std, 10x margin


@pytest.mark.parametrize("case_id, kind, params", CASES, ids=CASE_IDS)
def test_inverse_cdf_matches_scipy(case_id, kind, params):
    """The chaospy marginal that is sampled is the distribution whose moments are reported."""
    inp = _input(kind, params)
    u = np.array([1e-6, 0.01, 0.1, 0.3, 0.5, 0.7, 0.9, 0.99, 1 - 1e-6])
    # Bound: parameters from a solve with residual 1e-10 std, moved along the quantile by
    # |z| <= 4.8 std at these u, and chaospy's numerical inverses (to ~1e-10): << 1e-8 |x|.
    np.testing.assert_allclose(inp.inverse_cdf(u), REFERENCE[kind](params).ppf(u), rtol=1e-8)


@pytest.mark.parametrize("rule", ["sobol", "random"])
@pytest.mark.parametrize("case_id, kind, params", CASES, ids=CASE_IDS)
def test_sample_mean_and_std(case_id, kind, params, rule):
    """20,000 mapped points: sample mean and std within 4 standard errors of the exact ones."""
    inp = _input(kind, params)
    x = _sample([inp], rule)[:, 0]
    n = x.size
    se_mean = inp.std / math.sqrt(n)
    # Var(s^2) ~ (mu4 - sigma^4) / n; delta method for s = sqrt(s^2).
    se_std = math.sqrt((inp.fourth_central_moment - inp.variance**2) / n) / (2 * inp.std)
    assert abs(x.mean() - inp.mean) < 4 * se_mean
    assert abs(x.std(ddof=1) - inp.std) < 4 * se_std


# --------------------------------------------------------------------------------------------
# Small and moderate C.V., zero spread, extreme magnitudes
# --------------------------------------------------------------------------------------------

# cv -> 0: the expected skewness / kurtosis are the distributions' small-C.V. limits.
GUMBEL_SKEW = -12 * math.sqrt(6) * special.zeta(3, 1) / math.pi**3   # Weibull, shape -> inf
TINY = [
    ("normal", {"mean": 2.0, "cv": 1e-8}, 0.0, 3.0),
    ("truncnormal", {"mean": 2.0, "cv": 1e-8, "lower": 1.0, "upper": 3.0}, 0.0, 3.0),
    ("lognormal", {"mean": 2.0, "cv": 1e-8}, 3e-8, 3.0),          # skew = 3 cv + cv^3
    ("uniform", {"mean": 2.0, "cv": 1e-8}, 0.0, 1.8),
    ("weibull", {"mean": 2.0, "cv": 1e-8}, GUMBEL_SKEW, 5.4),
    ("beta", {"mean": 0.3, "cv": 1e-8}, None, 3.0),                # skew ~ 1e-8, from scipy
]


@pytest.mark.parametrize("kind, params, skew, kurt", TINY, ids=[t[0] for t in TINY])
def test_tiny_cv(kind, params, skew, kurt):
    """C.V. 1e-8: exact mean/std, the limiting shape, finite samples with the right spread."""
    inp = _input(kind, params)
    # Bound: the mean is what was asked, up to the solve's 1e-10 std = 2e-18 (below rounding).
    assert inp.mean == pytest.approx(params["mean"], rel=1e-12)
    assert inp.std == pytest.approx(1e-8 * params["mean"], rel=1e-8)   # residual 1e-10 of std
    if skew is None:
        skew = float(_ref_beta(params).stats(moments="s"))
    # Bound: the limits differ from the shape at cv = 1e-8 by O(cv) (constants < 100);
    # abs 1e-12 for symmetric cases, whose 0 is rounding of O(1) standardized moments.
    assert inp.skewness == pytest.approx(skew, rel=1e-6, abs=1e-12)
    assert inp.kurtosis == pytest.approx(kurt, rel=1e-6)
    x = _sample([inp], "sobol")[:, 0]
    assert np.all(np.isfinite(x))
    assert abs(x.mean() - inp.mean) < 4 * inp.std / math.sqrt(x.size)
    assert x.std(ddof=1) == pytest.approx(inp.std, rel=0.05)


def test_moment_form_cv_0_3_equals_std_form():
    """mean + cv and mean + std = cv |mean| describe the same input."""
    for kind in DISTRIBUTIONS:
        extra = {"lower": 0.5} if kind == "truncnormal" else {}
        a = _input(kind, {"mean": 0.6 if kind == "beta" else 2.0, "cv": 0.3, **extra})
        b = _input(kind, {"mean": 0.6 if kind == "beta" else 2.0,
                          "std": 0.3 * (0.6 if kind == "beta" else 2.0), **extra})
        # Bound: std = cv |mean| differs from the given std by at most an ulp, which the
        # moment solves amplify by their O(100) condition: ~1e-14.
        assert a.moments == pytest.approx(b.moments, rel=1e-12), kind


ZERO_SPREAD = [(kind, {"mean": 0.7, "std": 0.0}) for kind in DISTRIBUTIONS] + [
    ("normal", {"mean": 5.0, "cv": 0.0}),
    ("normal", {"mean": 0.0, "std": 0.0}),
    ("normal", {"mean": 0.0, "cv": 0.0}),
    ("truncnormal", {"mean": 1.0, "std": 0.0, "lower": 1.0, "upper": 2.0}),
    ("weibull", {"mean": 3.0, "std": 0.0, "lower": 1.0}),
    ("beta", {"mean": 2.0, "cv": 0.0, "lower": 1.0, "upper": 3.0}),
]


@pytest.mark.parametrize("kind, params", ZERO_SPREAD,
                         ids=[f"{k}-{i}" for i, (k, _) in enumerate(ZERO_SPREAD)])
def test_zero_std_is_a_constant(kind, params):
    inp = _input(kind, params)
    assert inp.mean == params["mean"]
    assert inp.variance == 0.0 and inp.std == 0.0
    assert inp.skewness == 0.0 and math.isnan(inp.kurtosis)
    u = np.array([1e-15, 0.25, 0.5, 0.999999])
    assert np.all(inp.inverse_cdf(u) == params["mean"])
    for rule in ("random", "sobol"):
        x = _sample([inp, _input("normal", {"mean": 1.0, "cv": 0.1}, name="y")], rule, n=256)
        assert np.all(x[:, 0] == params["mean"])


def test_lognormal_native_zero_sigma_is_constant():
    inp = _input("lognormal", {"mu": 0.5, "sigma": 0.0})
    # Bound: the same expression exp(mu), so equal up to the last ulp (2.2e-16).
    assert inp.mean == pytest.approx(math.exp(0.5), rel=1e-15) and inp.variance == 0.0
    assert np.all(inp.inverse_cdf(np.array([0.1, 0.9])) == inp.mean)


def test_zero_std_input_in_a_correlated_space():
    a = _input("normal", {"mean": 3.0, "std": 0.0}, name="a")
    b = _input("normal", {"mean": 1.0, "std": 0.5}, name="b")
    x = _sample([a, b], "random", n=1000, correlation=[[1.0, 0.5], [0.5, 1.0]])
    assert np.all(x[:, 0] == 3.0) and np.all(np.isfinite(x[:, 1]))


@pytest.mark.parametrize("scale", [1e12, 1e-12], ids=["1e12", "1e-12"])
@pytest.mark.parametrize("case_id, kind, params", CASES, ids=CASE_IDS)
def test_extreme_magnitudes(case_id, kind, params, scale):
    """Scaling every location/scale parameter by 1e+-12 scales the input exactly; shape stays."""
    base = _input(kind, params)
    shape_keys = {"cv", "shape", "alpha", "beta"} | ({"mu", "sigma"} if kind == "lognormal"
                                                     else set())
    scaled_params = {k: (v if k in shape_keys else v * scale) for k, v in params.items()}
    if kind == "lognormal" and "mu" in params:
        scaled_params["mu"] = params["mu"] + math.log(scale)
    if kind == "beta" and "lower" not in params:   # the default support [0, 1] scales too
        scaled_params.update(lower=0.0, upper=scale)
    inp = _input(kind, scaled_params)
    # Bound: two solves, each to a residual of 1e-10 std (condition O(10..100) on the
    # moments), plus one rounding of the scale: 1e-9 for the mean, 1e-8 for the std.
    assert inp.mean == pytest.approx(base.mean * scale, rel=1e-9)
    assert inp.std == pytest.approx(base.std * scale, rel=1e-8)
    # Shape moments: the same residuals through the third and fourth powers of std.
    assert inp.skewness == pytest.approx(base.skewness, rel=1e-7, abs=1e-9)
    assert inp.kurtosis == pytest.approx(base.kurtosis, rel=1e-8)
    mean, std, skew, kurt = _exact(REFERENCE[kind](scaled_params))
    # Bound as in test_moments_match_scipy (residual 1e-10 std × O(100) condition).
    assert inp.mean == pytest.approx(mean, rel=1e-8)
    assert inp.std == pytest.approx(std, rel=1e-8)
    u = np.array([0.001, 0.2, 0.5, 0.8, 0.999])
    # Bound as in test_inverse_cdf_matches_scipy: solve residuals × |z| <= 3.1, << 1e-8.
    np.testing.assert_allclose(inp.inverse_cdf(u), base.inverse_cdf(u) * scale, rtol=1e-8)
    x = _sample([inp], "sobol", n=4096)[:, 0]
    assert abs(x.mean() - inp.mean) < 4 * inp.std / math.sqrt(x.size)


def test_weibull_small_cv_moments_are_accurate():
    """Shape 200 and 1e6: central moments without the raw-moment cancellation.

    Reference: the exact limits as shape -> inf (cv = pi / (sqrt 6 k), skewness -> Gumbel,
    kurtosis -> 5.4) with their 1/k corrections bounded, and scipy's own values at shape 200,
    where its cancellation still leaves ~1e-6.
    """
    inp = _input("weibull", {"shape": 1e6, "scale": 1.0})
    assert inp.cv == pytest.approx(math.pi / (math.sqrt(6) * 1e6), rel=1e-5)
    assert inp.skewness == pytest.approx(GUMBEL_SKEW, rel=1e-5)
    assert inp.kurtosis == pytest.approx(5.4, rel=1e-5)
    inp = _input("weibull", {"shape": 200.0, "scale": 1.0})
    mean, std, skew, kurt = _exact(stats.weibull_min(200.0))
    # Bound: the mean Γ(1 + 1/k) is a closed form (~1e-15 each side); scipy's std comes from
    # E[X²] − E[X]², cancelling 1 − cv² with cv = 6.4e-3: 2.4e4 × eps ~ 5e-12 of var, so 1e-9
    # on the std leaves the margin of scipy's own gamma evaluations.
    assert inp.mean == pytest.approx(mean, rel=1e-12)
    assert inp.std == pytest.approx(std, rel=1e-9)
    assert inp.skewness == pytest.approx(skew, rel=1e-5)
    assert inp.kurtosis == pytest.approx(kurt, rel=1e-5)


# --------------------------------------------------------------------------------------------
# Validation: one-line StudyError naming the key
# --------------------------------------------------------------------------------------------

BAD = [
    ("negative-std", "normal", {"mean": 1.0, "std": -0.1}, "std"),
    ("negative-cv", "normal", {"mean": 1.0, "cv": -0.1}, "cv"),
    ("cv-on-zero-mean", "normal", {"mean": 0.0, "cv": 0.1}, "cv"),
    ("lognormal-zero-mean", "lognormal", {"mean": 0.0, "std": 0.1}, "mean"),
    ("lognormal-negative-mean", "lognormal", {"mean": -1.0, "cv": 0.1}, "mean"),
    ("lognormal-negative-mean-no-spread", "lognormal", {"mean": -1.0, "std": 0.0}, "mean"),
    ("lognormal-negative-sigma", "lognormal", {"mu": 0.0, "sigma": -1.0}, "sigma"),
    ("uniform-upper-equals-lower", "uniform", {"lower": 1.0, "upper": 1.0}, "upper"),
    ("uniform-upper-below-lower", "uniform", {"lower": 2.0, "upper": 1.0}, "upper"),
    ("beta-upper-below-lower", "beta", {"alpha": 2.0, "beta": 2.0, "lower": 2.0, "upper": 1.0},
     "upper"),
    ("truncnormal-upper-below-lower", "truncnormal",
     {"mu": 0.0, "sigma": 1.0, "lower": 1.0, "upper": 0.0}, "upper"),
    ("weibull-cv-too-large", "weibull", {"mean": 1.0, "cv": 1000.0}, "cv"),
    ("weibull-std-too-large", "weibull", {"mean": 1.0, "std": 1000.0}, "std"),
    ("weibull-mean-below-lower", "weibull", {"mean": 1.0, "cv": 0.1, "lower": 2.0}, "mean"),
    ("weibull-negative-shape", "weibull", {"shape": -1.0, "scale": 1.0}, "shape"),
    ("weibull-zero-scale", "weibull", {"shape": 2.0, "scale": 0.0}, "scale"),
    ("beta-std-too-large", "beta", {"mean": 0.3, "std": 0.5}, "std"),
    ("beta-cv-too-large", "beta", {"mean": 0.5, "cv": 1.2}, "cv"),
    ("beta-mean-outside", "beta", {"mean": 1.5, "std": 0.1}, "mean"),
    ("beta-negative-alpha", "beta", {"alpha": -1.0, "beta": 1.0}, "alpha"),
    ("truncnormal-mean-below", "truncnormal", {"mean": -1.0, "std": 0.1, "lower": 0.0}, "mean"),
    ("truncnormal-mean-above", "truncnormal",
     {"mean": 3.0, "std": 0.1, "lower": 0.0, "upper": 1.0}, "mean"),
    ("truncnormal-impossible-std", "truncnormal",
     {"mean": 0.5, "std": 0.3, "lower": 0.0, "upper": 1.0}, "std"),   # uniform has 0.2887
    ("truncnormal-zero-sigma", "truncnormal", {"mu": 0.0, "sigma": 0.0}, "sigma"),
    ("unknown-key", "normal", {"mean": 1.0, "std": 0.1, "sigma": 0.1}, "sigma"),
    ("unknown-key-lognormal", "lognormal", {"mean": 1.0, "std": 0.1, "shape": 2.0}, "shape"),
    ("std-and-cv", "normal", {"mean": 1.0, "std": 0.1, "cv": 0.1}, "cv"),
    ("mean-without-spread", "normal", {"mean": 1.0}, "std"),
    ("spread-without-mean", "normal", {"std": 1.0}, "mean"),
    ("nothing", "uniform", {}, "lower"),
    ("native-incomplete", "lognormal", {"mu": 1.0}, "sigma"),
    ("moment-and-native", "lognormal", {"mean": 1.0, "cv": 0.1, "mu": 0.0}, "mu"),
    ("moment-and-native-uniform", "uniform", {"mean": 1.0, "cv": 0.1, "lower": 0.0}, "lower"),
    ("nan-mean", "normal", {"mean": math.nan, "std": 0.1}, "mean"),
    ("inf-std", "normal", {"mean": 1.0, "std": math.inf}, "std"),
    ("inf-upper", "uniform", {"lower": 0.0, "upper": math.inf}, "upper"),
    ("string-mean", "normal", {"mean": "1.0", "std": 0.1}, "mean"),
    ("bool-cv", "normal", {"mean": 1.0, "cv": True}, "cv"),
]


@pytest.mark.parametrize("case_id, kind, params, bad_key", BAD, ids=[b[0] for b in BAD])
def test_bad_parameters_raise_study_error_naming_the_key(case_id, kind, params, bad_key):
    with pytest.raises(StudyError) as err:
        _input(kind, params, name="steel.E")
    assert err.value.key == f"inputs.steel.E.{bad_key}"
    assert f"inputs.steel.E.{bad_key}" in str(err.value)
    assert "\n" not in str(err.value)


def test_numpy_scalars_are_numbers():
    inp = _input("lognormal", {"mean": np.float32(2.0), "cv": np.float64(0.3)})
    # Bound: the lognormal's closed forms round at ~1e-15; a float32 2.0 is exactly 2.
    assert inp.mean == pytest.approx(2.0, rel=1e-12) and inp.cv == pytest.approx(0.3)
    inp = _input("uniform", {"lower": np.int64(1), "upper": np.int32(3)})
    assert inp.mean == 2.0
    with pytest.raises(StudyError, match="finite number"):
        _input("normal", {"mean": np.bool_(True), "std": 1.0})


def test_unknown_distribution():
    with pytest.raises(StudyError, match=r"inputs\.E\.distribution.*unknown distribution"):
        _input("gaussian", {"mean": 1.0, "std": 0.1}, name="E")
    with pytest.raises(StudyError) as err:
        make_distribution("cauchy", {}, key="inputs.E")
    assert err.value.key == "inputs.E.distribution"


def test_missing_name_or_distribution():
    with pytest.raises(StudyError) as err:
        RandomInput.from_spec({"distribution": "normal", "mean": 1.0, "std": 0.1})
    assert err.value.key == "inputs.name"
    with pytest.raises(StudyError) as err:
        RandomInput.from_spec({"name": "E", "mean": 1.0, "std": 0.1})
    assert err.value.key == "inputs.E.distribution"


def test_duplicate_input_names():
    with pytest.raises(StudyError, match="declared twice"):
        InputSpace([_input("normal", {"mean": 1.0, "std": 0.1}, name="E")] * 2)


# --------------------------------------------------------------------------------------------
# Correlation (Gaussian copula)
# --------------------------------------------------------------------------------------------

BAD_CORRELATION = [
    ("non-symmetric", [[1.0, 0.5, 0.0], [0.4, 1.0, 0.0], [0.0, 0.0, 1.0]]),
    ("diagonal-not-one", [[1.0, 0.0, 0.0], [0.0, 0.9, 0.0], [0.0, 0.0, 1.0]]),
    ("entry-above-one", [[1.0, 1.2, 0.0], [1.2, 1.0, 0.0], [0.0, 0.0, 1.0]]),
    ("entry-below-minus-one", [[1.0, -1.5, 0.0], [-1.5, 1.0, 0.0], [0.0, 0.0, 1.0]]),
    ("not-positive-definite", [[1.0, 0.9, -0.9], [0.9, 1.0, 0.9], [-0.9, 0.9, 1.0]]),
    ("singular", [[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
    ("wrong-shape", [[1.0, 0.0], [0.0, 1.0]]),
    ("not-square", [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
    ("ragged", [[1.0, 0.0, 0.0], [0.0, 1.0], [0.0, 0.0, 1.0]]),
    ("not-numbers", [["a", 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
    ("nan", [[1.0, math.nan, 0.0], [math.nan, 1.0, 0.0], [0.0, 0.0, 1.0]]),
    ("flat", [1.0, 0.0, 0.0]),
]


@pytest.mark.parametrize("case_id, matrix", BAD_CORRELATION, ids=[b[0] for b in BAD_CORRELATION])
def test_bad_correlation_raises(case_id, matrix):
    inputs = [_input("normal", {"mean": 1.0, "cv": 0.1}, name=n) for n in "abc"]
    with pytest.raises(StudyError) as err:
        InputSpace(inputs, matrix)
    assert err.value.key == "correlation.matrix"


def test_check_correlation_accepts_valid_and_rejects_bad():
    check_correlation(np.eye(3), 3)
    check_correlation(np.array([[1.0, -0.99], [-0.99, 1.0]]), 2)
    check_correlation(np.zeros((0, 0)), 0)
    with pytest.raises(StudyError, match="symmetric"):
        check_correlation(np.array([[1.0, 0.2], [0.1, 1.0]]), 2, key="study.correlation")
    with pytest.raises(StudyError, match="positive definite"):
        check_correlation(np.array([[1.0, 1.0], [1.0, 1.0]]), 2)


def test_uncorrelated_space_maps_columns_independently():
    a = _input("lognormal", {"mean": 2.0, "cv": 0.3}, name="a")
    b = _input("uniform", {"lower": 0.0, "upper": 4.0}, name="b")
    space = InputSpace([a, b])
    assert not space.is_correlated and space.names == ["a", "b"] and len(space) == 2
    assert space["b"] is b
    u = np.array([[0.1, 0.2], [0.5, 0.5], [0.9, 0.75]])
    x = space.from_unit_hypercube(u)
    # Bound: the same inverse CDF on the same u (no copula when uncorrelated): identical, up
    # to an ulp; the uniform's lower + (upper - lower) u rounds once, < 1e-14 relative.
    np.testing.assert_allclose(x[:, 0], a.inverse_cdf(u[:, 0]), rtol=1e-15)
    np.testing.assert_allclose(x[:, 1], [0.8, 2.0, 3.0], rtol=1e-14)
    summary = space.summary()
    # Bound: closed-form moments (lognormal from its moment form, uniform exact), ~1e-15.
    np.testing.assert_allclose(summary["input_mean"], [2.0, 2.0], rtol=1e-12)
    np.testing.assert_allclose(summary["input_cv"], [0.3, 4 / math.sqrt(12) / 2], rtol=1e-12)


def test_correlated_normals_have_the_pearson_correlation():
    """Normal marginals: the copula correlation is the Pearson correlation of the inputs."""
    rho = 0.7
    a = _input("normal", {"mean": 10.0, "cv": 0.1}, name="a")
    b = _input("normal", {"mean": -3.0, "std": 2.0}, name="b")
    c = _input("normal", {"mean": 1.0, "std": 0.5}, name="c")
    corr = [[1.0, rho, 0.0], [rho, 1.0, 0.0], [0.0, 0.0, 1.0]]
    for rule in ("random", "sobol"):
        x = _sample([a, b, c], rule, correlation=corr)
        n = x.shape[0]
        r = np.corrcoef(x.T)
        se = (1 - rho**2) / math.sqrt(n)          # standard error of Pearson's r (normal data)
        assert abs(r[0, 1] - rho) < 4 * se
        assert abs(r[0, 2]) < 4 / math.sqrt(n) and abs(r[1, 2]) < 4 / math.sqrt(n)
        # marginals unchanged
        for k, inp in enumerate((a, b, c)):
            assert abs(x[:, k].mean() - inp.mean) < 4 * inp.std / math.sqrt(n)
            assert x[:, k].std(ddof=1) == pytest.approx(inp.std, abs=4 * inp.std / math.sqrt(2 * n))


def test_correlated_lognormals_keep_their_marginals():
    """Non-normal marginals under the copula: each column still has its own distribution;
    the rank correlation is the copula's (Spearman = 6/pi asin(rho/2)) and Pearson's is the
    lognormal Nataf value (exp(rho s1 s2) - 1) / sqrt((exp(s1^2) - 1)(exp(s2^2) - 1))."""
    rho = 0.7
    a = _input("lognormal", {"mean": 2.0, "cv": 0.5}, name="a")
    b = _input("lognormal", {"mean": 5.0, "cv": 0.8}, name="b")
    x = _sample([a, b], "random", correlation=[[1.0, rho], [rho, 1.0]])
    n = x.shape[0]
    for k, inp in enumerate((a, b)):
        ref = _ref_lognormal({"mean": inp.mean, "cv": inp.cv})
        ks = stats.kstest(x[:, k], ref.cdf)
        assert ks.statistic < 1.95 / math.sqrt(n)        # KS at the 0.1 % level
        assert abs(x[:, k].mean() - inp.mean) < 4 * inp.std / math.sqrt(n)
    spearman = stats.spearmanr(x[:, 0], x[:, 1]).statistic
    rs = 6 / math.pi * math.asin(rho / 2)
    assert abs(spearman - rs) < 4 * 1.1 * (1 - rs**2) / math.sqrt(n)
    s1, s2 = math.sqrt(math.log1p(0.5**2)), math.sqrt(math.log1p(0.8**2))
    pearson_exact = math.expm1(rho * s1 * s2) / math.sqrt(math.expm1(s1**2) * math.expm1(s2**2))
    assert pearson_exact < rho - 0.02   # the point of the test: Pearson is not the copula rho
    assert abs(np.corrcoef(x.T)[0, 1] - pearson_exact) < 0.02


def test_copula_tail_stays_finite():
    """Points at the clipped corner map to finite values even where cdf(z) rounds to 1."""
    a = _input("normal", {"mean": 0.0, "std": 1.0}, name="a")
    b = _input("normal", {"mean": 0.0, "std": 1.0}, name="b")
    space = InputSpace([a, b], [[1.0, 0.7], [0.7, 1.0]])
    u = np.array([[1 - 1e-16, 1 - 1e-16], [0.0, 0.0], [1e-300, 1e-300]])
    x = space.from_unit_hypercube(u)
    assert np.all(np.isfinite(x))
    assert x[0, 0] > 7 and x[0, 1] > 7 and x[1, 0] < -7 and x[1, 1] < -7


# --------------------------------------------------------------------------------------------
# float64 limits (issue 8): overflow is a one-line error naming the key, never a traceback
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("kind, params, key", [
    ("normal", {"mean": 1.0, "std": 1e78}, "std"),            # std^4 = 1e312 (docs: ~1e77)
    ("normal", {"mean": 1.0, "std": 1e308}, "std"),           # the OverflowError
    ("normal", {"mean": 1e300, "cv": 1e300}, "cv"),           # std = cv |mean| = inf
    ("lognormal", {"mu": 0.0, "sigma": 30.0}, "sigma"),       # exp(sigma^2) overflows
    ("lognormal", {"mu": 700.0, "sigma": 1.0}, "mu"),         # exp(4 mu) in the 4th moment
    ("lognormal", {"mean": 1e300, "cv": 0.1}, "mean"),
    ("weibull", {"shape": 2.0, "scale": 1e300}, "scale"),
    ("weibull", {"shape": 0.01, "scale": 1.0}, "shape"),      # Γ(1 + 4/shape) overflows
    ("uniform", {"lower": -1e308, "upper": 1e308}, "lower"),  # upper - lower = inf
    ("beta", {"alpha": 1e300, "beta": 1e300}, "alpha"),
    ("beta", {"mean": 0.5, "std": 1e-300}, "std"),            # std^2 underflows to 0
    ("truncnormal", {"mean": 0.0, "std": 1e300, "lower": -1.0, "upper": 1.0}, "std"),
    ("truncnormal", {"mu": 0.0, "sigma": 1e300}, "sigma"),
])
def test_parameters_beyond_float64_are_one_line_errors(kind, params, key):
    with pytest.raises(StudyError) as err:
        _input(kind, params, name="steel.E")
    assert err.value.key == f"inputs.steel.E.{key}", str(err.value)
    assert "\n" not in str(err.value)


def test_std_up_to_1e76_is_representable():
    """docs/inputs.md: a normal's std must stay below about 1e77 (std^4 < 1.8e308)."""
    inp = _input("normal", {"mean": 1.0, "std": 1e76})
    assert math.isfinite(inp.fourth_central_moment)
    with pytest.raises(StudyError, match="overflow"):
        _input("normal", {"mean": 1.0, "std": 1e78})


def test_infinite_sampling_extremes_are_refused():
    """The tails sampling can reach (UNIT_CLIP, documented as 1e-15) must be finite."""
    from uqflow.inputs import UNIT_CLIP, _check_representable
    assert UNIT_CLIP == 1e-15
    with pytest.raises(StudyError, match="quantiles") as err:
        # Finite moments stated, tails that are not: the guard reads the tails themselves.
        _check_representable(chaospy.Normal(0.0, 1e308), (0.0, 1.0, 0.0, 3.0),
                             {"mean": 0.0, "std": 1e308}, "inputs[0]")
    assert err.value.key == "inputs[0].std"
