"""The von Mises-Fisher-Nakagami density, the cross-entropy method's family for high dimensions.

A direction x = u/|u| ~ vMF(mu, kappa) on the sphere S^(d-1) and an independent radius
r = |u| ~ Nakagami(m, Omega) (Wang & Song 2016; Papaioannou, Geyer & Straub 2019): in many
dimensions the standard normal's mass lies on a thin shell of radius about sqrt(d), and the
failure region's part of it is a cap of that shell, which d + 2 numbers describe (a mean
direction, a concentration, the radius' shape and mean square) where a Gaussian fitted to a
few hundred points misplaces its d means. ``VonMisesFisherNakagami`` samples, gives log q and
the likelihood ratio log phi - log q; ``fit_von_mises_fisher_nakagami`` is the weighted
maximum-likelihood fit of the cross-entropy update. docs/importance_sampling.md gives the
equations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import special
from scipy import stats as sps


#: the fitted concentration's cap: the direction's spread 1/sqrt(kappa) stays above 1e-4
#: radians (a fit to one point would give kappa = infinity and a density of one direction)
MAX_KAPPA = 1e8
#: the least fitted concentration (scipy's vMF refuses 0, the uniform direction itself)
MIN_KAPPA = 1e-8
#: the radius' spread a fit keeps, relative to half the standard normal's (``radius_shape_cap``;
#: importance_sampling.COVARIANCE_FLOOR is the Gaussians' same margin)
RADIUS_FLOOR = 0.6


def log_sphere_area(d: int) -> float:
    """log |S^(d-1)| = log(2 pi^(d/2) / Gamma(d/2)), the area of the unit sphere in R^d."""
    return math.log(2.0) + 0.5 * d * math.log(math.pi) - float(special.gammaln(0.5 * d))


def normalized_weights(log_weights) -> np.ndarray:
    log_weights = np.asarray(log_weights, dtype=float).ravel()
    if not (np.all(log_weights < np.inf) and np.any(np.isfinite(log_weights))):
        raise ValueError("some weight must be positive and finite, none infinite")
    w = np.exp(log_weights - np.max(log_weights))
    return w / w.sum()


# ------------------------------------------------------------------ von Mises-Fisher-Nakagami

@dataclass(frozen=True, eq=False)
class VonMisesFisherNakagami:
    """q(u) of u = r x: x ~ vMF(mean_direction, kappa) on S^(d-1), r ~ Nakagami(m, omega)
    (E r^2 = omega), independent. In u-space q(u) = f_R(r) f_vMF(x) / r^(d-1)."""

    mean_direction: np.ndarray
    kappa: float
    m: float
    omega: float

    def __post_init__(self):
        mu = np.asarray(self.mean_direction, dtype=float).ravel()
        if mu.size < 2 or not np.all(np.isfinite(mu)) or np.linalg.norm(mu) == 0:
            raise ValueError("a von Mises-Fisher-Nakagami density needs a finite nonzero "
                             "mean direction in at least 2 dimensions")
        for name, value in (("kappa", self.kappa), ("m", self.m), ("omega", self.omega)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        mu = mu / np.linalg.norm(mu)
        object.__setattr__(self, "mean_direction", mu)
        object.__setattr__(self, "_direction", sps.vonmises_fisher(mu, float(self.kappa)))
        object.__setattr__(self, "_radius", sps.nakagami(float(self.m),
                                                         scale=math.sqrt(self.omega)))

    @property
    def dimension(self) -> int:
        return self.mean_direction.size

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` draws (n, d): the directions first, then the radii, from ``rng``."""
        x = np.atleast_2d(self._direction.rvs(int(n), random_state=rng)).reshape(n, -1)
        r = np.asarray(self._radius.rvs(size=int(n), random_state=rng), dtype=float)
        return r[:, None] * x

    def log_pdf(self, u: np.ndarray) -> np.ndarray:
        """log q(u) per row of ``u`` (n, d) in u-space (with the Jacobian r^-(d-1))."""
        u, r = self._radii(u)
        return (self._radius.logpdf(r) + self._direction.logpdf(u / r[:, None])
                - (self.dimension - 1) * np.log(r))

    def log_likelihood_ratio(self, u: np.ndarray) -> np.ndarray:
        """log phi(u) - log q(u): under phi the radius is chi_d and the direction uniform,
        so the ratio is chi_d(r) / |S^(d-1)| over f_R(r) f_vMF(x) (the r^(d-1) cancel)."""
        u, r = self._radii(u)
        d = self.dimension
        return (sps.chi.logpdf(r, d) - log_sphere_area(d) - self._radius.logpdf(r)
                - self._direction.logpdf(u / r[:, None]))

    def _radii(self, u):
        u = np.atleast_2d(np.asarray(u, dtype=float))
        if u.shape[1] != self.dimension:
            raise ValueError(f"points of dimension {u.shape[1]} for a density of dimension "
                             f"{self.dimension}")
        return u, np.linalg.norm(u, axis=1)


def fit_von_mises_fisher_nakagami(u, log_weights) -> VonMisesFisherNakagami:
    """The weighted fit of a vMFN density to the points ``u`` (n, d) with weights w_i =
    exp(log_weights) (normalized; n_e = 1 / sum w_i^2 their effective count, Kish's):
    mu = sum w x / |sum w x| (x = u/|u|); kappa by Banerjee et al.'s (2005) approximation
    R (d - R^2) / (1 - R^2) of the mean resultant length R, taken free of the noise of n_e
    points (E|sum w x|^2 = R^2 + (1 - R^2) / n_e, solved for R^2); Nakagami's moments
    Omega = E_w r^2 and m = Omega^2 / Var_w(r^2), the variance with the reliability-weights
    factor 1 / (1 - 1/n_e) (unbiased), m clipped to [1/2, Omega / (2 floor)]:
    ``radius_shape_cap``."""
    u = np.atleast_2d(np.asarray(u, dtype=float))
    w = normalized_weights(log_weights)
    if u.shape[0] != w.size or not np.all(np.isfinite(u)):
        raise ValueError(f"need {u.shape[0]} finite points with a weight each, got "
                         f"{w.size} weights")
    d = u.shape[1]
    r = np.linalg.norm(u, axis=1)
    if np.any(r[w > 0] == 0):
        raise ValueError("a point at the origin has no direction")
    x = u / np.where(r > 0, r, 1.0)[:, None]
    resultant = w @ x
    length = float(np.linalg.norm(resultant))
    if length == 0:
        raise ValueError("the weighted directions cancel: no mean direction")
    squares = float(np.sum(w**2))  # 1 / n_e
    signal = (length**2 - squares) / (1.0 - squares) if squares < 1.0 else length**2
    concentration = math.sqrt(min(max(signal, 0.0), 1.0 - 1e-15))
    kappa = min(max(concentration * (d - concentration**2) / (1.0 - concentration**2),
                    MIN_KAPPA), MAX_KAPPA)
    omega = float(w @ r**2)
    spread = float(w @ (r**2 - omega) ** 2) / (1.0 - squares) if squares < 1.0 else 0.0
    cap = radius_shape_cap(omega)
    m = cap if spread <= omega**2 / cap else min(max(omega**2 / spread, 0.5), cap)
    return VonMisesFisherNakagami(resultant / length, kappa, m, omega)


def radius_shape_cap(omega: float, floor: float = RADIUS_FLOOR) -> float:
    """The largest Nakagami shape m a fit keeps: Omega / (2 floor), at least 1/2. The
    weights chi_d(r) / f_R(r) have a finite second moment under f_R only if m < Omega
    (chi_d^2 / f_R grows like exp(-(1 - m/Omega) r^2)); in r, Nakagami's variance is about
    Omega / (4 m) and the standard normal's 1/2, so m < Omega is the radius' spread above
    half the standard normal's, the same bound as a Gaussian's variance above 1/2, and the
    floor keeps the same margin as COVARIANCE_FLOOR (0.6 of it)."""
    return max(omega / (2.0 * floor), 0.5)
