"""Random inputs: one chaospy marginal per uncertain parameter, joined by a Gaussian copula.

``RandomInput`` is a named marginal with its units and its first four moments;
``InputSpace`` joins inputs with an optional correlation matrix (Nataf transform) and maps
points of the unit hypercube to parameter values. Samplers live in ``uqflow.sampling``.
"""

from __future__ import annotations

import math
import numbers
import warnings
from dataclasses import dataclass, field

import chaospy
import numpy as np
from scipy import integrate, optimize, special, stats

from uqflow.errors import StudyError
from uqflow.layout import INPUT_CV, INPUT_MEAN, INPUT_SKEWNESS, INPUT_STD

DISTRIBUTIONS = ("normal", "truncnormal", "lognormal", "uniform", "weibull", "beta")

# Keys each distribution accepts besides name/units; "mean"+("std"|"cv") is the moment form.
_NATIVE = {
    "normal": set(),
    "truncnormal": {"mu", "sigma", "lower", "upper"},
    "lognormal": {"mu", "sigma"},
    "uniform": {"lower", "upper"},
    "weibull": {"shape", "scale", "lower"},
    "beta": {"alpha", "beta", "lower", "upper"},
}
# Native keys that also go with the moment form (the support), by distribution.
_SUPPORT = {
    "normal": set(),
    "truncnormal": {"lower", "upper"},
    "lognormal": set(),
    "uniform": set(),
    "weibull": {"lower"},
    "beta": {"lower", "upper"},
}


@dataclass(frozen=True)
class RandomInput:
    """A named uncertain parameter.

    ``distribution`` is a chaospy distribution; ``kind`` the family name used in study files.
    """

    name: str
    distribution: chaospy.Distribution
    kind: str = "custom"
    units: str = ""
    moments: tuple[float, float, float, float] = field(default=(np.nan,) * 4, repr=False)

    def __post_init__(self):
        if np.isnan(self.moments[0]):
            object.__setattr__(self, "moments", _central_moments(self.distribution))

    @property
    def mean(self) -> float:
        return self.moments[0]

    @property
    def variance(self) -> float:
        return self.moments[1]

    @property
    def std(self) -> float:
        return math.sqrt(self.moments[1])

    @property
    def cv(self) -> float:
        return self.std / abs(self.mean) if self.mean != 0 else math.inf

    @property
    def third_central_moment(self) -> float:
        return self.moments[2]

    @property
    def fourth_central_moment(self) -> float:
        return self.moments[3]

    @property
    def skewness(self) -> float:
        return self.moments[2] / self.moments[1] ** 1.5 if self.moments[1] > 0 else 0.0

    @property
    def kurtosis(self) -> float:
        return self.moments[3] / self.moments[1] ** 2 if self.moments[1] > 0 else math.nan

    def inverse_cdf(self, u: np.ndarray) -> np.ndarray:
        if self.variance == 0:
            return np.full(np.shape(u), self.mean)
        return np.asarray(self.distribution.inv(np.asarray(u, dtype=float)), dtype=float)

    @classmethod
    def from_spec(cls, spec: dict) -> "RandomInput":
        """Build from a study-file table (``name``, ``distribution``, parameters, ``units``)."""
        spec = dict(spec)
        name = spec.pop("name", None)
        if not isinstance(name, str) or not name:
            raise StudyError(f"every input needs a name (a string), got {name!r}",
                             key="inputs.name")
        if "distribution" not in spec:
            raise StudyError(f"missing (one of {', '.join(DISTRIBUTIONS)})",
                             key=f"inputs.{name}.distribution")
        kind = spec.pop("distribution")
        units = spec.pop("units", "") or ""
        if not isinstance(units, str):
            raise StudyError(f"must be a string, got {units!r}", key=f"inputs.{name}.units")
        dist, moments = make_distribution(kind, spec, key=f"inputs.{name}")
        return cls(name=name, distribution=dist, kind=kind, units=units, moments=moments)


def _central_moments(dist) -> tuple[float, float, float, float]:
    return _central_from_raw(np.asarray(dist.mom([1, 2, 3, 4]), dtype=float))


def make_distribution(kind: str, params: dict, key: str = "input"):
    """Return ``(chaospy distribution, central moments)`` for a study-file parameter table.

    Raises ``StudyError`` naming ``key`` for impossible parameters.
    """
    if not isinstance(kind, str) or kind not in DISTRIBUTIONS:
        raise StudyError(f"unknown distribution '{kind}' (known: {', '.join(DISTRIBUTIONS)})",
                         key=f"{key}.distribution")
    params = {k: v for k, v in params.items() if v is not None}
    allowed = _NATIVE[kind] | {"mean", "std", "cv"}
    for k in params:
        if k not in allowed:
            raise StudyError(f"'{k}' is not a parameter of a {kind} distribution "
                             f"(it takes {', '.join(sorted(allowed))})", key=f"{key}.{k}")
    for k, v in params.items():
        if not isinstance(v, numbers.Real) or isinstance(v, (bool, np.bool_)) \
                or isinstance(v, int) and abs(v) >= 2**1024 or not math.isfinite(v):
            raise StudyError(f"must be a finite number, got {v!r}", key=f"{key}.{k}")

    moment_form = "mean" in params
    if moment_form:
        mean = float(params["mean"])
        if "std" in params and "cv" in params:
            raise StudyError("give either std or cv, not both", key=f"{key}.cv")
        if "std" in params:
            std = float(params["std"])
            if std < 0:
                raise StudyError(f"std must be >= 0, got {std:g}", key=f"{key}.std")
        elif "cv" in params:
            cv = float(params["cv"])
            if cv < 0:
                raise StudyError(f"cv must be >= 0, got {cv:g}", key=f"{key}.cv")
            if mean == 0 and cv > 0:
                raise StudyError("cv needs a nonzero mean (give std instead)", key=f"{key}.cv")
            std = cv * abs(mean)
            if not math.isfinite(std):
                raise StudyError(f"cv × |mean| = std overflows a float64 (cv {cv:g}, mean "
                                 f"{mean:g})", key=f"{key}.cv")
        else:
            raise StudyError("a mean needs a spread: give std or cv", key=f"{key}.std")
    elif "std" in params or "cv" in params:
        raise StudyError("std/cv need a mean", key=f"{key}.mean")

    try:
        # Overflow in numpy and scipy warns and gives inf/NaN, which the checks below refuse
        # in one line; a warning printed as well would make the error two.
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore", RuntimeWarning)
            dist, moments = _build(kind, params, key, mean if moment_form else None,
                                   std if moment_form else None)
            _check_representable(dist, moments, params, key)
    except OverflowError:
        # Python floats raise where numpy would return inf: the moments are beyond float64.
        raise StudyError("its moments overflow a float64; rescale the parameter (e.g. to "
                         "other units)", key=_largest_key(params, key)) from None
    except ZeroDivisionError:
        raise StudyError("the spread is too small for float64 next to the other parameters "
                         "(its square underflows); use std = 0 for a constant",
                         key=_spread_key(params, key) if moment_form
                         else _smallest_key(params, key)) from None
    return dist, moments


def _build(kind, params, key, mean, std):
    builder = _BUILDERS[kind]
    if mean is not None:
        # Native shape parameters next to mean+std/cv would be silently ignored: refuse them.
        # Only the support bounds (lower/upper) go with the moment form.
        mixed = sorted(set(params) & (_NATIVE[kind] - _SUPPORT[kind]))
        if mixed:
            raise StudyError(f"give either mean and std/cv or the native parameters "
                             f"({', '.join(sorted(_NATIVE[kind]))}), not both",
                             key=f"{key}.{mixed[0]}")
        if std == 0:
            builder.check_point(mean, params, key)
            return _point(mean)
        return builder.from_moments(mean, std, params, key)
    return builder.from_native(params, key)


# Sampling maps the unit hypercube clipped to [UNIT_CLIP, 1 - UNIT_CLIP] through the inverse
# CDF: the values there are the most extreme a design can hold, so they must be finite.
UNIT_CLIP = 1e-15


def _check_representable(dist, moments, params, key) -> None:
    """Refuse a distribution whose four moments or sampled extremes are not finite floats.

    Every method reads the moments (Taylor the third and fourth, the design the kurtosis), and
    a design point at the clipped tails must be a number the solver can take.
    """
    if not all(math.isfinite(m) for m in moments):
        raise StudyError("its first four moments are not all finite float64 numbers (the "
                         "fourth grows as std^4: keep std below about 1e77, in other units "
                         "if need be)",
                         key=_largest_key(params, key))
    if moments[1] > 0:
        with np.errstate(all="ignore"):
            tails = np.asarray(dist.inv(np.array([UNIT_CLIP, 1 - UNIT_CLIP])), dtype=float)
        if not np.all(np.isfinite(tails)):
            raise StudyError(f"its {UNIT_CLIP:g} and {1 - UNIT_CLIP:.15g} quantiles (the "
                             f"extremes sampling can draw) are not finite float64 numbers",
                             key=_largest_key(params, key))


def _largest_key(params, key) -> str:
    """The parameter of largest magnitude: the one to blame for an overflow."""
    name = max(params, key=lambda k: abs(float(params[k])))
    return f"{key}.{name}"


def _smallest_key(params, key) -> str:
    name = min(params, key=lambda k: abs(float(params[k])))
    return f"{key}.{name}"


def _spread_key(params, key):
    """The key a spread error should name: the one the study file used."""
    return f"{key}.{'cv' if 'cv' in params else 'std'}"


def _point(value: float):
    # chaospy has no Dirac distribution; a one-ulp uniform is never sampled (inverse_cdf
    # short-circuits on zero variance) but keeps the object a chaospy distribution.
    value = float(value)
    return chaospy.Uniform(value, np.nextafter(value, np.inf)), (value, 0.0, 0.0, 0.0)


def _need(params, names, key, kind):
    missing = [n for n in names if n not in params]
    if missing:
        raise StudyError(f"a {kind} distribution needs {', '.join(names)} "
                         f"(or mean and std/cv)", key=f"{key}.{missing[0]}")


class _Normal:
    @staticmethod
    def check_point(mean, params, key):
        pass

    @staticmethod
    def from_moments(mean, std, params, key):
        return chaospy.Normal(mean, std), (mean, std**2, 0.0, 3 * std**4)

    @staticmethod
    def from_native(params, key):
        _need(params, ["mean", "std"], key, "normal")


class _LogNormal:
    @staticmethod
    def check_point(mean, params, key):
        if mean <= 0:
            raise StudyError(f"a lognormal mean must be > 0, got {mean:g}", key=f"{key}.mean")

    @staticmethod
    def from_moments(mean, std, params, key):
        _LogNormal.check_point(mean, params, key)
        s2 = math.log1p((std / mean) ** 2)
        return _LogNormal._make(math.log(mean) - s2 / 2, math.sqrt(s2))

    @staticmethod
    def from_native(params, key):
        _need(params, ["mu", "sigma"], key, "lognormal")
        if params["sigma"] < 0:
            raise StudyError("sigma must be >= 0", key=f"{key}.sigma")
        if params["sigma"] == 0:
            return _point(math.exp(params["mu"]))
        return _LogNormal._make(float(params["mu"]), float(params["sigma"]))

    @staticmethod
    def _make(mu, sigma):
        dist = chaospy.LogNormal(mu, sigma)
        # Closed forms in w = exp(sigma^2) - 1: differences of raw moments would cancel
        # catastrophically at small C.V. (at C.V. 1e-8 they return noise).
        m = math.exp(mu + 0.5 * sigma * sigma)
        w = math.expm1(sigma * sigma)
        var = m * m * w
        mu3 = m**3 * w * w * (w + 3)
        mu4 = var * var * (3 + w * (16 + w * (15 + w * (6 + w))))
        return dist, (m, var, mu3, mu4)


class _Uniform:
    @staticmethod
    def check_point(mean, params, key):
        pass

    @staticmethod
    def from_moments(mean, std, params, key):
        half = math.sqrt(3.0) * std
        return _Uniform._make(mean - half, mean + half, key)

    @staticmethod
    def from_native(params, key):
        _need(params, ["lower", "upper"], key, "uniform")
        return _Uniform._make(float(params["lower"]), float(params["upper"]), key)

    @staticmethod
    def _make(lo, hi, key):
        if not hi > lo:
            raise StudyError(f"upper ({hi:g}) must exceed lower ({lo:g})", key=f"{key}.upper")
        w = hi - lo
        return chaospy.Uniform(lo, hi), ((lo + hi) / 2, w * w / 12, 0.0, w**4 / 80)


class _Weibull:
    # Shapes searched for a requested C.V.: 0.1 .. 1e9 covers C.V. ~ 430 .. 1.3e-9.
    SHAPES = (0.1, 1.0e9)

    @staticmethod
    def check_point(mean, params, key):
        shift = float(params.get("lower", 0.0))
        if mean < shift:
            raise StudyError(f"a Weibull mean must be >= its lower bound {shift:g}",
                             key=f"{key}.mean")

    @staticmethod
    def from_moments(mean, std, params, key):
        shift = float(params.get("lower", 0.0))
        if mean <= shift:
            raise StudyError(f"a Weibull mean must exceed its lower bound {shift:g}",
                             key=f"{key}.mean")
        cv = std / (mean - shift)

        def cv_of(k):
            return math.sqrt(math.expm1(_log_raw_ratio(2, k)))

        # cv falls monotonically with shape; solve in log(shape).
        lo, hi = _Weibull.SHAPES
        if not cv_of(hi) < cv < cv_of(lo):
            raise StudyError(f"C.V. {cv:g} (of mean - lower) is outside what a Weibull can have "
                             f"here ({cv_of(hi):.3g} .. {cv_of(lo):.3g})",
                             key=_spread_key(params, key))
        log_shape = optimize.brentq(lambda t: cv_of(math.exp(t)) / cv - 1,
                                    math.log(lo), math.log(hi), xtol=1e-15, rtol=1e-15)
        shape = math.exp(log_shape)
        scale = (mean - shift) / math.exp(_lgamma1p(1 / shape))
        return _Weibull._make(shape, scale, shift, key)

    @staticmethod
    def from_native(params, key):
        _need(params, ["shape", "scale"], key, "weibull")
        return _Weibull._make(float(params["shape"]), float(params["scale"]),
                              float(params.get("lower", 0.0)), key)

    @staticmethod
    def _make(shape, scale, shift, key):
        if shape <= 0:
            raise StudyError(f"shape must be > 0, got {shape:g}", key=f"{key}.shape")
        if scale <= 0:
            raise StudyError(f"scale must be > 0, got {scale:g}", key=f"{key}.scale")
        if shape < _Weibull.SHAPES[0] / 2:
            raise StudyError(f"shape must be >= {_Weibull.SHAPES[0] / 2:g} (its fourth moment "
                             f"overflows below), got {shape:g}", key=f"{key}.shape")
        m1 = scale * math.exp(_lgamma1p(1 / shape))
        c2, c3, c4 = _weibull_relative_moments(shape)
        moments = (m1 + shift, c2 * m1**2, c3 * m1**3, c4 * m1**4)
        if not all(math.isfinite(v) for v in moments):
            raise StudyError(f"the moments of a Weibull with shape {shape:g} and scale "
                             f"{scale:g} overflow", key=f"{key}.scale")
        return chaospy.Weibull(shape, scale, shift), moments


_EULER_GAMMA = 0.57721566490153286
_ZETA_N = np.arange(2, 40)
_ZETA = special.zeta(_ZETA_N.astype(float), 1)


def _lgamma1p(x: float) -> float:
    """log Gamma(1 + x), accurate also for tiny x (where gammaln(1 + x) loses digits)."""
    if abs(x) < 0.2:
        return float(-_EULER_GAMMA * x + np.sum((-1.0) ** _ZETA_N * _ZETA * x**_ZETA_N / _ZETA_N))
    return float(special.gammaln(1 + x))


def _log_raw_ratio(r: int, shape: float) -> float:
    """log(E[X^r] / E[X]^r) of a Weibull, summed as one series at large shape (no cancellation)."""
    x = 1.0 / shape
    if r * x < 0.2:
        n = _ZETA_N
        return float(np.sum((-1.0) ** n * _ZETA * (float(r) ** n - r) * x**n / n))
    return _lgamma1p(r * x) - r * _lgamma1p(x)


def _weibull_relative_moments(shape: float) -> tuple[float, float, float]:
    """Central moments 2, 3, 4 of a Weibull divided by mean^2, mean^3, mean^4.

    At small shape the raw-moment formulas are exact enough; at large shape (small C.V.) they
    cancel catastrophically, so the third and fourth are integrated over log X instead:
    with S = log E, E ~ Exp(1), X / E[X] = exp(S / shape - log Gamma(1 + 1/shape)).
    """
    c2 = math.expm1(_log_raw_ratio(2, shape))
    if shape < 2:
        e2, e3, e4 = (math.exp(_log_raw_ratio(r, shape)) for r in (2, 3, 4))
        return c2, e3 - 3 * e2 + 2, e4 - 4 * e3 + 6 * e2 - 3
    l1 = _lgamma1p(1 / shape)

    def integrand(s, j):
        return math.expm1(s / shape - l1) ** j * math.exp(s - math.exp(s))

    # Absolute tolerances on the scale of std^j: the third moment passes through 0 (shape 3.6).
    c3, c4 = (integrate.quad(integrand, -60.0, 6.0, args=(j,), epsabs=1e-13 * c2 ** (j / 2),
                             epsrel=1e-13, limit=200)[0] for j in (3, 4))
    return c2, c3, c4


class _Beta:
    # Beyond this alpha + beta, scipy's incomplete-beta inverse loses accuracy (and returns
    # NaN near 1e16); such a beta (C.V. ~ 1e-6 or less, skewness ~ 1e-6) is sampled as the
    # normal with its mean and std. Its reported moments stay the beta's.
    NORMAL_ABOVE = 1.0e12

    @staticmethod
    def check_point(mean, params, key):
        lo, hi = float(params.get("lower", 0.0)), float(params.get("upper", 1.0))
        if not hi > lo:
            raise StudyError(f"upper ({hi:g}) must exceed lower ({lo:g})", key=f"{key}.upper")
        if not lo <= mean <= hi:
            raise StudyError(f"mean {mean:g} is not inside [{lo:g}, {hi:g}]", key=f"{key}.mean")

    @staticmethod
    def from_moments(mean, std, params, key):
        lo, hi = float(params.get("lower", 0.0)), float(params.get("upper", 1.0))
        if not hi > lo:
            raise StudyError(f"upper ({hi:g}) must exceed lower ({lo:g})", key=f"{key}.upper")
        m, s = (mean - lo) / (hi - lo), std / (hi - lo)
        if not 0 < m < 1:
            raise StudyError(f"mean {mean:g} is not strictly inside [{lo:g}, {hi:g}]",
                             key=f"{key}.mean")
        if s * s >= m * (1 - m):
            raise StudyError(f"no beta distribution on [{lo:g}, {hi:g}] has mean {mean:g} and "
                             f"std {std:g} (the std must be below "
                             f"{math.sqrt(m * (1 - m)) * (hi - lo):.4g})",
                             key=_spread_key(params, key))
        nu = m * (1 - m) / (s * s) - 1
        return _Beta._make(m * nu, (1 - m) * nu, lo, hi, key)

    @staticmethod
    def from_native(params, key):
        _need(params, ["alpha", "beta"], key, "beta")
        return _Beta._make(float(params["alpha"]), float(params["beta"]),
                           float(params.get("lower", 0.0)), float(params.get("upper", 1.0)), key)

    @staticmethod
    def _make(a, b, lo, hi, key):
        for k, v in (("alpha", a), ("beta", b)):
            if v <= 0:
                raise StudyError(f"{k} must be > 0, got {v:g}", key=f"{key}.{k}")
        if not hi > lo:
            raise StudyError(f"upper ({hi:g}) must exceed lower ({lo:g})", key=f"{key}.upper")
        w = hi - lo
        m1, var, skew, exkurt = (float(x) for x in stats.beta(a, b).stats(moments="mvsk"))
        std = math.sqrt(var)
        moments = (lo + w * m1, w * w * var, skew * (w * std) ** 3,
                   (exkurt + 3) * (w * std) ** 4)
        if a + b > _Beta.NORMAL_ABOVE:
            return chaospy.Normal(moments[0], w * std), moments
        return chaospy.Beta(a, b, lower=lo, upper=hi), moments


class _TruncNormal:
    @staticmethod
    def check_point(mean, params, key):
        lo, hi = float(params.get("lower", -math.inf)), float(params.get("upper", math.inf))
        _TruncNormal._check_bounds(lo, hi, key)
        if not lo <= mean <= hi:
            raise StudyError(f"mean {mean:g} is not inside [{lo:g}, {hi:g}]", key=f"{key}.mean")

    @staticmethod
    def from_moments(mean, std, params, key):
        lo, hi = float(params.get("lower", -math.inf)), float(params.get("upper", math.inf))
        _TruncNormal._check_bounds(lo, hi, key)
        if not lo < mean < hi:
            raise StudyError(f"mean {mean:g} is not inside [{lo:g}, {hi:g}]", key=f"{key}.mean")

        # Find the parent normal whose truncation has the requested mean and std. Solved in
        # units of the requested std around its mean (mu = mean + std z0, sigma = std e^z1),
        # so the solver's steps and tolerances fit any magnitude (1e-12 .. 1e12).
        lo_s, hi_s = (lo - mean) / std, (hi - mean) / std

        def residual(z):
            sigma = math.exp(z[1])
            m, v = _truncnorm_mv((lo_s - z[0]) / sigma, (hi_s - z[0]) / sigma)
            return [z[0] + sigma * m, sigma * math.sqrt(v) - 1.0]

        # gtol too: near the uniform limit the std hardly changes with sigma, and the default
        # gtol stopped there with a 3e-8 residual (and a false "no truncated normal" error).
        try:
            sol = optimize.least_squares(residual, [0.0, 0.0], xtol=1e-15, ftol=1e-15,
                                         gtol=1e-15)
        except ValueError:
            # Residuals not finite at the start: the std dwarfs the bounds (or the reverse).
            sol = None
        if sol is None or not sol.success or max(abs(r) for r in sol.fun) > 1e-10:
            raise StudyError(f"no truncated normal on [{lo:g}, {hi:g}] has mean {mean:g} and "
                             f"std {std:g}", key=_spread_key(params, key))
        return _TruncNormal._make(mean + std * sol.x[0], std * math.exp(sol.x[1]), lo, hi, key)

    @staticmethod
    def from_native(params, key):
        _need(params, ["mu", "sigma"], key, "truncnormal")
        lo, hi = float(params.get("lower", -math.inf)), float(params.get("upper", math.inf))
        if params["sigma"] <= 0:
            raise StudyError(f"sigma must be > 0, got {params['sigma']:g}", key=f"{key}.sigma")
        return _TruncNormal._make(float(params["mu"]), float(params["sigma"]), lo, hi, key)

    @staticmethod
    def _check_bounds(lo, hi, key):
        if not hi > lo:
            raise StudyError(f"upper ({hi:g}) must exceed lower ({lo:g})", key=f"{key}.upper")

    @staticmethod
    def _make(mu, sigma, lo, hi, key):
        _TruncNormal._check_bounds(lo, hi, key)
        a, b = (lo - mu) / sigma, (hi - mu) / sigma
        # Standardized moments, scaled here: scipy's own loc/scale path fails at 1e+-12.
        m1, var, skew, exkurt = (float(x) for x in stats.truncnorm.stats(a, b, moments="mvsk"))
        if not (math.isfinite(m1) and var > 0):
            raise StudyError(f"the normal(mu={mu:g}, sigma={sigma:g}) has no usable mass in "
                             f"[{lo:g}, {hi:g}]", key=f"{key}.sigma")
        std = sigma * math.sqrt(var)
        return (chaospy.TruncNormal(lower=lo, upper=hi, mu=mu, sigma=sigma),
                (mu + sigma * m1, std * std, skew * std**3, (exkurt + 3) * std**4))


def _truncnorm_mv(a, b):
    """Mean and variance of the standard normal truncated to [a, b]."""
    m, v = stats.truncnorm.stats(a, b, moments="mv")
    return float(m), float(v)


def _central_from_raw(raw):
    m1, m2, m3, m4 = raw
    var = m2 - m1**2
    mu3 = m3 - 3 * m1 * m2 + 2 * m1**3
    mu4 = m4 - 4 * m1 * m3 + 6 * m1**2 * m2 - 3 * m1**4
    return (float(m1), float(max(var, 0.0)), float(mu3), float(max(mu4, 0.0)))


_BUILDERS = {"normal": _Normal, "truncnormal": _TruncNormal, "lognormal": _LogNormal,
             "uniform": _Uniform, "weibull": _Weibull, "beta": _Beta}


class InputSpace:
    """Joint distribution of the random inputs.

    Marginals are joined by a Gaussian copula (Nataf transform): ``correlation`` is the
    correlation of the underlying standard normals. For normal marginals it is the Pearson
    correlation of the inputs themselves; for others it is close to it (the Taylor method
    uses it as the Pearson correlation, an approximation stated in docs/methods.md).
    """

    def __init__(self, inputs: list[RandomInput], correlation: np.ndarray | None = None,
                 key: str = "correlation"):
        names = [i.name for i in inputs]
        if len(set(names)) != len(names):
            dup = next(n for n in names if names.count(n) > 1)
            raise StudyError(f"input '{dup}' is declared twice", key="inputs.name")
        self.inputs = list(inputs)
        n = len(inputs)
        if correlation is None:
            correlation = np.eye(n)
        try:
            correlation = np.asarray(correlation, dtype=float)
        except (TypeError, ValueError):
            raise StudyError(f"must be a {n}x{n} matrix of numbers (one row per input)",
                             key=f"{key}.matrix") from None
        check_correlation(correlation, n, key)
        self.correlation = correlation
        self._cholesky = np.linalg.cholesky(correlation) if n else np.zeros((0, 0))

    @property
    def names(self) -> list[str]:
        return [i.name for i in self.inputs]

    def __len__(self) -> int:
        return len(self.inputs)

    def __getitem__(self, name: str) -> RandomInput:
        return self.inputs[self.names.index(name)]

    @property
    def is_correlated(self) -> bool:
        return bool(np.any(self.correlation != np.eye(len(self))))

    @property
    def means(self) -> np.ndarray:
        return np.array([i.mean for i in self.inputs])

    @property
    def stds(self) -> np.ndarray:
        return np.array([i.std for i in self.inputs])

    def from_unit_hypercube(self, u: np.ndarray) -> np.ndarray:
        """Map points ``u`` of shape (n_points, n_inputs) in (0, 1)^n to parameter values."""
        u = np.clip(np.asarray(u, dtype=float), UNIT_CLIP, 1 - UNIT_CLIP)
        if self.is_correlated:
            z = stats.norm.ppf(u) @ self._cholesky.T
            # A correlated z can reach where cdf rounds to exactly 1 (or 0): an infinite input.
            u = np.clip(stats.norm.cdf(z), UNIT_CLIP, 1 - UNIT_CLIP)
        return np.column_stack([inp.inverse_cdf(u[:, k]) for k, inp in enumerate(self.inputs)]) \
            if len(self) else np.zeros((u.shape[0], 0))

    def summary(self) -> dict[str, np.ndarray]:
        """Mean, std, C.V. and skewness of every input (stored with every result)."""
        return {
            INPUT_MEAN: self.means,
            INPUT_STD: self.stds,
            INPUT_CV: np.array([i.cv for i in self.inputs]),
            INPUT_SKEWNESS: np.array([i.skewness for i in self.inputs]),
        }


def check_correlation(matrix: np.ndarray, n: int, key: str = "correlation") -> None:
    """Raise ``StudyError`` unless ``matrix`` is an n×n symmetric positive definite correlation."""
    if matrix.shape != (n, n):
        raise StudyError(f"must be {n}x{n} (one row per input), got {matrix.shape}",
                         key=f"{key}.matrix")
    if not np.all(np.isfinite(matrix)):
        raise StudyError("has non-finite entries", key=f"{key}.matrix")
    if not np.allclose(matrix, matrix.T, rtol=0, atol=1e-12):
        raise StudyError("must be symmetric", key=f"{key}.matrix")
    if not np.allclose(np.diag(matrix), 1.0, rtol=0, atol=1e-12):
        raise StudyError("diagonal must be 1", key=f"{key}.matrix")
    if np.any(np.abs(matrix) > 1):
        raise StudyError("entries must lie in [-1, 1]", key=f"{key}.matrix")
    if n and np.linalg.eigvalsh(matrix).min() <= 1e-12:
        raise StudyError(f"is not positive definite (smallest eigenvalue "
                         f"{np.linalg.eigvalsh(matrix).min():.3g})", key=f"{key}.matrix")
