"""Random fields of material properties: Karhunen–Loève expansion with Weibull germs.

A ``FieldSpec`` (one ``[[fields]]`` table of a study) describes a spatially correlated
perturbation of one or more solver parameters. ``RandomField`` builds its truncated KL basis
(``KLBasis``) on the solver's points once; one realization of the field is then fixed by its
*germs* ξ (one number per mode, drawn by ``GermSpec.draw``):

    value(x) = mean(x) · (1 + amplitude · δ(x)),     δ(x) = Σ_j sqrt(λ_j) φ_j(x) ξ_j

with (λ_j, φ_j) the eigenpairs of a unit-variance correlation kernel on the solver's domain.
This is seed 002's eq. 26 (M = M̄ + sign(randn)·wblrnd(1, 2)·M̄/10) made spatially correlated
by its KL truncation, eq. 27. The design stores germs, never field values; ``FieldSample``
turns one realization's germs back into values wherever a solver asks for them.

The model, the numerics and measured accuracy are described in docs/fields.md.
"""

from __future__ import annotations

import math
import re
import unicodedata
from collections.abc import Mapping
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator
from scipy import optimize, special

from uqflow.layout import FIELD_PREFIX, GERM_PREFIX

__all__ = ["GermSpec", "FieldSpec", "KLBasis", "RandomField", "FieldSample", "germ_seed"]

KERNELS = ("exponential", "squared_exponential")
# Nodes of the 2-D Nyström problem per unit of ``quadrature_points`` (400 -> 2000 nodes).
NODES_2D_PER_QUADRATURE_POINT = 5
# Eigenvalues below this fraction of the largest are not "available" modes (numerical noise).
_RELATIVE_EIGENVALUE_FLOOR = 1e-10
# Evaluate kernels in blocks of at most this many entries (memory bound of ``modes_at``).
_BLOCK_ENTRIES = 1 << 22
# ``RandomField`` caches mode values of up to this many entries per point set.
_CACHE_ENTRIES = 1 << 23
_CACHE_SLOTS = 4
# Upper bounds, so that what validates can run (docs/study-files.md, "Limits"). The mode
# values at the solver's points are points × modes float64: 320,000 MPM particles × 1,000
# modes = 2.4 GiB.
MAX_KL_MODES = 1000
# The 2-D Nyström matrix is (5 × quadrature_points)² float64 and its eigendecomposition
# O(n³): 2,000 points give 10,000 nodes, a 0.75 GiB matrix and minutes of LAPACK.
MAX_QUADRATURE_POINTS = 2000
# Near this Weibull shape of the germs Γ(1 + 2/shape) nears the float64 limit (Γ(171) ~ 7e306).
MIN_GERM_SHAPE = 0.012
# Clipped values are put this fraction of |mean| inside the admissible interval.
CLIP_MARGIN = 1e-3


# --------------------------------------------------------------------------- germs
class GermSpec(BaseModel):
    """The distribution of the KL germs ξ_j (independent, zero mean).

    ``symmetric-weibull``: ξ = s · W with s = sign of a standard normal (±1 with p = 1/2)
    and W ~ Weibull(scale, shape), seed 002 eq. 26 (MATLAB ``sign(randn())*wblrnd(1, 2)``).
    ``gaussian``: ξ ~ N(0, 1) (``scale``/``shape`` are ignored).
    """

    # Strict like every study table: no booleans or strings for numbers, no NaN/infinity.
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)

    kind: Literal["gaussian", "symmetric-weibull"] = "symmetric-weibull"
    scale: float = Field(1.0, gt=0, allow_inf_nan=False,
                         description="Weibull scale of |ξ| (symmetric-weibull only)")
    # Γ(1 + 2/shape), the germs' second moment, overflows a float64 below shape 2/170.
    shape: float = Field(2.0, ge=MIN_GERM_SHAPE, allow_inf_nan=False,
                         description="Weibull shape of |ξ| (symmetric-weibull only)")

    @model_validator(mode="after")
    def _finite_second_moment(self):
        if not math.isfinite(self.second_moment()):
            raise ValueError(f"the germs' second moment scale² Γ(1 + 2/shape) overflows a "
                             f"float64 (scale {self.scale:g}, shape {self.shape:g})")
        return self

    def second_moment(self) -> float:
        """E[ξ²]: 1 for gaussian, scale² Γ(1 + 2/shape) for symmetric-weibull."""
        if self.kind == "gaussian":
            return 1.0
        # scale * scale, not scale**2: a float power raises OverflowError, a product is inf.
        return self.scale * self.scale * math.gamma(1.0 + 2.0 / self.shape)

    def draw(self, size, rng: np.random.Generator) -> np.ndarray:
        """``size`` independent germs from ``rng``.

        symmetric-weibull draws all the signs first (standard normals), then all the
        magnitudes, so the stream layout is fixed for a given size.
        """
        if self.kind == "gaussian":
            return rng.standard_normal(size)
        sign = np.where(rng.standard_normal(size) < 0, -1.0, 1.0)
        return sign * (self.scale * rng.weibull(self.shape, size))


# --------------------------------------------------------------------------- field spec
class FieldSpec(BaseModel):
    """One ``[[fields]]`` table: a correlated random perturbation of solver parameters."""

    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)

    name: str = Field(min_length=1)
    parameters: list[str] | None = Field(
        None, description="solver parameters the field drives (default: [name])")
    kernel: Literal["exponential", "squared_exponential"] = "exponential"
    correlation_length: float = Field(gt=0, allow_inf_nan=False)
    modes: int | None = Field(None, ge=1, le=MAX_KL_MODES,
                              description="number of KL modes kept")
    captured_variance: float | None = Field(
        None, gt=0, le=1, description="keep the fewest modes capturing this variance share")
    germ: GermSpec = Field(default_factory=GermSpec)
    divisor: float | None = Field(None, gt=0, allow_inf_nan=False,
                                  description="amplitude = 1/divisor (seed eq. 26: 10)")
    cv: float | None = Field(None, ge=0, allow_inf_nan=False,
                             description="amplitude = cv / sqrt(E[germ^2])")
    quadrature_points: int = Field(400, ge=8, le=MAX_QUADRATURE_POINTS,
                                   description="Nyström grid size")
    store_values: bool = False

    @field_validator("name")
    @classmethod
    def _visible_name(cls, name):
        # The name reaches netCDF variable names and one-line messages.
        if not name.strip() or any(unicodedata.category(c) == "Cc" for c in name):
            raise ValueError(f"must be a visible name (not blank, no control characters), "
                             f"got {name!r}")
        return name

    @model_validator(mode="after")
    def _resolve_defaults(self):
        if self.modes is not None and self.captured_variance is not None:
            raise ValueError("give either modes or captured_variance, not both")
        if self.modes is None and self.captured_variance is None:
            self.captured_variance = 0.95
        if self.divisor is not None and self.cv is not None:
            raise ValueError("give either divisor or cv, not both")
        if self.divisor is None and self.cv is None:
            self.divisor = 10.0
        if self.parameters is not None:
            if not self.parameters:
                raise ValueError("parameters must name at least one solver parameter")
            if any(not p for p in self.parameters):
                raise ValueError("parameter names must not be empty")
            if len(set(self.parameters)) != len(self.parameters):
                raise ValueError("parameters are listed twice")
        return self

    @property
    def targets(self) -> list[str]:
        """The solver parameters this field drives."""
        return list(self.parameters) if self.parameters is not None else [self.name]

    @property
    def amplitude(self) -> float:
        """Multiplier of δ(x): 1/divisor, or cv / sqrt(E[ξ²])."""
        if self.cv is not None:
            return self.cv / math.sqrt(self.germ.second_moment())
        return 1.0 / self.divisor


# --------------------------------------------------------------------------- kernels
def _kernel(kind: str, r: np.ndarray, b: float) -> np.ndarray:
    """Unit-variance correlation at distance ``r``: exp(-r/b) or exp(-(r/b)²)."""
    if kind == "exponential":
        return np.exp(-r / b)
    return np.exp(-np.square(r / b))


def _kernel_integral_1d(kind: str, x: np.ndarray, lo: float, hi: float, b: float) -> np.ndarray:
    """∫_lo^hi C(x, y) dy, exactly (x anywhere on the line)."""
    def prim(t):  # ∫_0^t C(|u|) du
        if kind == "exponential":
            return np.sign(t) * b * -np.expm1(-np.abs(t) / b)
        return 0.5 * math.sqrt(math.pi) * b * special.erf(t / b)
    return prim(hi - x) - prim(lo - x)


def _distances(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Euclidean distances between rows of p (n, k) and q (m, k), shape (n, m)."""
    if p.shape[1] == 1:
        return np.abs(p[:, :1] - q[:, 0][None, :])
    d = p[:, None, :] - q[None, :, :]
    return np.sqrt(np.einsum("nmk,nmk->nm", d, d))


def _blocks(n: int, m: int):
    step = max(1, _BLOCK_ENTRIES // max(m, 1))
    for start in range(0, n, step):
        yield slice(start, min(n, start + step))


# --------------------------------------------------------------------------- KL basis
class KLBasis:
    """Truncated Karhunen–Loève basis of a unit-variance kernel on a box domain.

    Build with ``KLBasis.build``. ``modes_at(x)`` returns sqrt(λ_j) φ_j(x) with φ_j
    L²-orthonormal over the domain, so δ(x) = modes_at(x) @ ξ has, for germs of unit second
    moment, covariance Σ_j λ_j φ_j(x) φ_j(y) — the kernel minus its truncated tail.

    Attributes: ``eigenvalues`` (kept, descending), ``n_modes``, ``captured_fraction``
    (Σ kept λ / domain measure), ``total_variance`` (the domain measure, = Σ of all λ),
    ``method`` ("analytic", "nystrom" or "point"), ``available_modes``, ``capped`` (the request
    could not be met with the available modes), ``nodes``/``weights`` (Nyström quadrature).
    """

    def __init__(self):  # use KLBasis.build
        self.nodes = None
        self.weights = None
        self._corrected = False

    # ---------------------------------------------------------------- construction
    @classmethod
    def build(cls, kernel: str, correlation_length: float, domain_points,
              modes: int | None = None, captured_variance: float | None = None,
              quadrature_points: int = 400, *,
              method: Literal["auto", "analytic", "nystrom"] = "auto") -> "KLBasis":
        """The basis on the bounding interval (1-D) or box (2-D) of ``domain_points`` (n, d).

        ``method="auto"`` uses the analytic eigenpairs for the 1-D exponential kernel and
        Nyström otherwise; "analytic" or "nystrom" force one (for validation).
        """
        if kernel not in KERNELS:
            raise ValueError(f"unknown kernel '{kernel}' (known: {', '.join(KERNELS)})")
        b = float(correlation_length)
        if not (math.isfinite(b) and b > 0):
            raise ValueError(f"correlation_length must be a finite number > 0, got {b!r}")
        if modes is not None and captured_variance is not None:
            raise ValueError("give either modes or captured_variance, not both")
        if modes is None and captured_variance is None:
            captured_variance = 0.95
        if modes is not None and int(modes) < 1:
            raise ValueError(f"modes must be >= 1, got {modes}")
        if captured_variance is not None and not 0 < captured_variance <= 1:
            raise ValueError(f"captured_variance must lie in (0, 1], got {captured_variance}")
        quadrature_points = int(quadrature_points)
        if quadrature_points < 8:
            raise ValueError(f"quadrature_points must be >= 8, got {quadrature_points}")
        if method not in ("auto", "analytic", "nystrom"):
            raise ValueError(f"unknown method '{method}'")

        pts = np.asarray(domain_points, dtype=float)
        if pts.ndim == 1:
            pts = pts[:, None]
        if pts.ndim != 2 or pts.shape[1] not in (1, 2) or pts.shape[0] == 0:
            raise ValueError(f"domain points must have shape (n, 1) or (n, 2) with n >= 1, "
                             f"got {np.shape(domain_points)}")
        if not np.all(np.isfinite(pts)):
            raise ValueError("domain points must be finite")

        self = cls()
        self.kernel = kernel
        self.correlation_length = b
        self.dim = pts.shape[1]
        self.lower = pts.min(axis=0)
        self.upper = pts.max(axis=0)
        extent = self.upper - self.lower
        # An axis along which the points (nearly) coincide does not count: points on a line
        # in 2-D get the 1-D basis, coincident points a single random variable.
        self.axes = np.flatnonzero(extent > 1e-12 * float(np.max(np.abs(pts))))
        self.requested_modes = None if modes is None else int(modes)
        self.requested_fraction = None if captured_variance is None else float(captured_variance)
        self.quadrature_points = quadrature_points
        active = pts[:, self.axes]

        if self.axes.size == 0:
            self._build_point()
        elif self.axes.size == 1 and kernel == "exponential" and method != "nystrom":
            self._build_analytic()
        elif method == "analytic":
            raise ValueError("analytic eigenpairs exist only for the exponential kernel in 1-D")
        elif self.axes.size == 1:
            self._build_nystrom_1d()
        else:
            self._build_nystrom_2d(active)
        self.n_modes = int(self.eigenvalues.size)
        self.captured_fraction = float(self.eigenvalues.sum() / self.total_variance)
        return self

    def _truncate(self, eigenvalues: np.ndarray) -> int:
        """How many of the (descending, available) eigenvalues to keep; sets ``capped``."""
        n = eigenvalues.size
        if self.requested_modes is not None:
            keep = min(self.requested_modes, n)
            self.capped = keep < self.requested_modes
            return keep
        target = self.requested_fraction * self.total_variance
        csum = np.cumsum(eigenvalues)
        reached = np.flatnonzero(csum >= target * (1 - 1e-12))
        if reached.size:
            self.capped = False
            return int(reached[0]) + 1
        self.capped = True
        return n

    def _available(self, eigenvalues: np.ndarray) -> int:
        if eigenvalues.size == 0 or eigenvalues[0] <= 0:
            return 0
        return int(np.count_nonzero(eigenvalues > _RELATIVE_EIGENVALUE_FLOOR * eigenvalues[0]))

    def _build_point(self):
        """All points coincide: the field is one random variable (one mode, φ = 1)."""
        self.method = "point"
        self.total_variance = 1.0
        self.available_modes = 1
        self.eigenvalues = np.ones(1)
        self.capped = self.requested_modes is not None and self.requested_modes > 1

    def _build_analytic(self):
        """Exponential kernel on [c - a, c + a] (Ghanem & Spanos 1991, sec. 2.3.3).

        With t = ω a and ca = a/b: even modes solve ca cos t - t sin t = 0 on
        [kπ, kπ + π/2], odd modes t cos t + ca sin t = 0 on [(k - 1/2)π, kπ]; the brackets
        alternate, so mode j (0-based) is even for even j and the roots come out sorted.
        """
        self.method = "analytic"
        ax = self.axes[0]
        lo, hi = float(self.lower[ax]), float(self.upper[ax])
        a = 0.5 * (hi - lo)
        self._centre = 0.5 * (lo + hi)
        self._a = a
        c = 1.0 / self.correlation_length
        ca = a * c
        self.total_variance = 2.0 * a
        cap = self.quadrature_points
        want = cap if self.requested_modes is None else min(self.requested_modes, cap)
        target = None if self.requested_fraction is None else \
            self.requested_fraction * self.total_variance * (1 - 1e-12)

        def even(t):
            return ca * math.cos(t) - t * math.sin(t)

        def odd(t):
            return t * math.cos(t) + ca * math.sin(t)

        roots, total = [], 0.0
        for j in range(want):
            if j % 2 == 0:
                k = j // 2
                t = optimize.brentq(even, k * math.pi, k * math.pi + 0.5 * math.pi,
                                    xtol=1e-15, rtol=1e-15)
            else:
                k = (j + 1) // 2
                t = optimize.brentq(odd, (k - 0.5) * math.pi, k * math.pi,
                                    xtol=1e-15, rtol=1e-15)
            roots.append(t)
            total += 2 * c / ((t / a) ** 2 + c * c)
            if target is not None and total >= target:
                break
        t = np.array(roots)
        omega = t / a
        lam = 2 * c / (omega**2 + c * c)
        self.available_modes = cap
        keep = self._truncate(lam)
        if self.requested_modes is not None and self.requested_modes > cap:
            self.capped = True
        self._omega = omega[:keep]
        self._even = (np.arange(keep) % 2) == 0
        sinc2 = np.sin(2 * t[:keep]) / (2 * t[:keep])
        self._norm = np.sqrt(a * np.where(self._even, 1 + sinc2, 1 - sinc2))
        self.eigenvalues = lam[:keep]

    def _solve(self, matrix: np.ndarray, weights: np.ndarray):
        """Eigenpairs of a symmetrised Nyström matrix: eigenvalues (kept) and nodal φ."""
        ev, vec = np.linalg.eigh(matrix)
        ev, vec = ev[::-1], vec[:, ::-1]
        self.available_modes = self._available(ev)
        keep = self._truncate(ev[:self.available_modes])
        phi = vec[:, :keep] / np.sqrt(weights)[:, None]
        # A fixed sign per mode (LAPACK's is arbitrary): positive projection on a generic
        # smooth function of the normalised coordinates.
        u = (self.nodes - 0.5 * (self._lo + self._hi)) / (self._hi - self._lo)
        probe = np.exp(0.5 + u @ np.array([0.61, 0.37])[:u.shape[1]])
        flip = (weights * probe) @ phi < 0
        phi[:, flip] *= -1
        return ev[:keep].copy(), phi

    def _build_nystrom_1d(self):
        """Gauss–Legendre Nyström with singularity subtraction (1-D, either kernel).

        ∫ C(x_i, y) φ(y) dy = ∫ C(x_i, y)(φ(y) - φ(x_i)) dy + φ(x_i) I(x_i), I exact: the
        integrand of the first term vanishes at the kernel's kink, so the eigenvalues
        converge as N^-4 for the exponential kernel instead of N^-2. The matrix stays
        symmetric: W^½ C W^½ + diag(I - C w).
        """
        self.method = "nystrom"
        ax = self.axes[0]
        lo, hi = float(self.lower[ax]), float(self.upper[ax])
        self._lo, self._hi = np.array([lo]), np.array([hi])
        a, centre = 0.5 * (hi - lo), 0.5 * (lo + hi)
        t, wq = np.polynomial.legendre.leggauss(self.quadrature_points)
        x = centre + a * t
        w = a * wq
        self.nodes, self.weights = x[:, None], w
        self.total_variance = hi - lo
        b = self.correlation_length
        C = _kernel(self.kernel, np.abs(x[:, None] - x[None, :]), b)
        err = _kernel_integral_1d(self.kernel, x, lo, hi, b) - C @ w
        sw = np.sqrt(w)
        S = sw[:, None] * C * sw[None, :]
        S[np.diag_indices_from(S)] += err
        self.eigenvalues, self._phi = self._solve(S, w)
        self._corrected = True

    def _build_nystrom_2d(self, active: np.ndarray):
        """Nyström on the domain points themselves (equal weights = box area / nodes).

        Unique points are the nodes (sorted, so the basis does not depend on the point
        order); above ``NODES_2D_PER_QUADRATURE_POINT * quadrature_points`` unique points,
        one representative per cell of a regular grid of about that many cells over the box
        (the point nearest the cell centre) is used instead.
        """
        self.method = "nystrom"
        lo, hi = active.min(axis=0), active.max(axis=0)
        self._lo, self._hi = lo, hi
        nodes = np.unique(active, axis=0)
        budget = NODES_2D_PER_QUADRATURE_POINT * self.quadrature_points
        if nodes.shape[0] > budget:
            nodes = _cell_representatives(nodes, lo, hi, budget)
        area = float(np.prod(hi - lo))
        w = np.full(nodes.shape[0], area / nodes.shape[0])
        self.nodes, self.weights = nodes, w
        self.total_variance = area
        C = _kernel(self.kernel, _distances(nodes, nodes), self.correlation_length)
        self.eigenvalues, self._phi = self._solve(w[0] * C, w)

    # ---------------------------------------------------------------- evaluation
    def _points(self, points) -> np.ndarray:
        """Points as (n, d) float, then restricted to the active axes."""
        p = np.asarray(points, dtype=float)
        if p.ndim == 1 and self.dim == 1:
            p = p[:, None]
        elif p.ndim == 0 and self.dim == 1:
            p = p.reshape(1, 1)
        if p.ndim != 2 or p.shape[1] != self.dim:
            raise ValueError(f"points must have shape (n, {self.dim})"
                             f"{' or (n,)' if self.dim == 1 else ''}, got {np.shape(points)}")
        if not np.all(np.isfinite(p)):
            raise ValueError("points must be finite")
        return p[:, self.axes]

    def eigenfunctions(self, points) -> np.ndarray:
        """φ_j at ``points``, shape (n_points, n_modes) (L²-orthonormal over the domain)."""
        return self.modes_at(points) / np.sqrt(self.eigenvalues)

    def modes_at(self, points) -> np.ndarray:
        """sqrt(λ_j) φ_j(x) at ``points`` (shape (n,) or (n, d)); shape (n, n_modes)."""
        x = self._points(points)
        if self.method == "point":
            return np.ones((x.shape[0], 1))
        if self.method == "analytic":
            u = (x[:, 0] - self._centre)[:, None] * self._omega[None, :]
            vals = np.where(self._even[None, :], np.cos(u), np.sin(u))
            return vals * (np.sqrt(self.eigenvalues) / self._norm)[None, :]
        return self._extend(x, self._phi / np.sqrt(self.eigenvalues)[None, :])

    def field_at(self, points, germs) -> np.ndarray:
        """δ(x) = modes_at(points) @ germs without forming the (n, n_modes) matrix
        (Nyström: one kernel row per point against the nodal values of δ / λ)."""
        g = np.asarray(germs, dtype=float)
        if self.method != "nystrom":
            return self.modes_at(points) @ g
        return self._extend(self._points(points), self._phi @ (g / np.sqrt(self.eigenvalues)))

    def _extend(self, x: np.ndarray, nodal: np.ndarray) -> np.ndarray:
        """Nyström extension of nodal values f_k (columns, or one vector) to x:
        Σ_k w_k C(x, x_k) f_k, plus E(x) f(x) for the corrected 1-D scheme, where
        E(x) = ∫C(x, y) dy - Σ_k w_k C(x, x_k) and f(x) is interpolated linearly (the
        explicit form of the corrected equation, exact at the nodes; E is small wherever
        the grid resolves the kernel)."""
        n = x.shape[0]
        out = np.empty((n,) + nodal.shape[1:])
        weighted = self.weights.reshape((-1,) + (1,) * (nodal.ndim - 1)) * nodal
        b = self.correlation_length
        for blk in _blocks(n, self.nodes.shape[0]):
            xb = x[blk]
            K = _kernel(self.kernel, _distances(xb, self.nodes), b)
            vals = K @ weighted
            if self._corrected:
                err = _kernel_integral_1d(self.kernel, xb[:, 0], float(self._lo[0]),
                                          float(self._hi[0]), b) - K @ self.weights
                vals += err.reshape((-1,) + (1,) * (nodal.ndim - 1)) * \
                    self._interpolation(xb[:, 0], nodal)
            out[blk] = vals
        return out

    def _interpolation(self, x: np.ndarray, nodal: np.ndarray) -> np.ndarray:
        """Nodal values linearly interpolated to ``x`` (constant beyond the end nodes)."""
        xn = self.nodes[:, 0]
        i = np.clip(np.searchsorted(xn, x), 1, xn.size - 1)
        s = np.clip((x - xn[i - 1]) / (xn[i] - xn[i - 1]), 0.0, 1.0)
        s = s.reshape((-1,) + (1,) * (nodal.ndim - 1))
        return (1.0 - s) * nodal[i - 1] + s * nodal[i]

    @property
    def warning(self) -> str | None:
        """A one-line warning when the truncation request could not be met, else None."""
        if not self.capped:
            return None
        if self.requested_modes is not None:
            return (f"{self.requested_modes} KL modes requested but only {self.n_modes} "
                    f"available (captured variance {self.captured_fraction:.3g})")
        return (f"captured variance {self.requested_fraction:g} not reached: {self.n_modes} "
                f"modes (all available) capture {self.captured_fraction:.3g}; the correlation "
                f"length {self.correlation_length:g} is short for the grid — raise "
                f"quadrature_points or the correlation length")

    def __repr__(self) -> str:
        return (f"KLBasis({self.kernel}, b={self.correlation_length:g}, {self.method}, "
                f"modes={self.n_modes}, captured={self.captured_fraction:.4f})")


def _cell_representatives(points: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                          cells: int) -> np.ndarray:
    """One point per occupied cell of a ~``cells``-cell grid over [lo, hi]: the point
    nearest the cell centre (ties: the first in sorted order). Deterministic."""
    ext = hi - lo
    nx = max(1, int(round(math.sqrt(cells * ext[0] / ext[1]))))
    ny = max(1, cells // nx)
    counts = np.array([nx, ny])
    idx = np.minimum(((points - lo) / ext * counts).astype(int), counts - 1)
    centre = lo + (idx + 0.5) * ext / counts
    dist = np.sum(((points - centre) / ext) ** 2, axis=1)
    cell = idx[:, 0] * ny + idx[:, 1]
    order = np.lexsort((np.arange(len(points)), dist, cell))
    first = np.unique(cell[order], return_index=True)[1]
    return points[np.sort(order[first])]


# --------------------------------------------------------------------------- random field
class RandomField:
    """A ``FieldSpec`` with its KL basis on a solver's points; picklable (shipped to workers)."""

    def __init__(self, spec: FieldSpec, domain_points):
        if not isinstance(spec, FieldSpec):
            spec = FieldSpec.model_validate(spec)
        self._spec = spec
        self.basis = KLBasis.build(spec.kernel, spec.correlation_length, domain_points,
                                   modes=spec.modes, captured_variance=spec.captured_variance,
                                   quadrature_points=spec.quadrature_points)
        self._cache = ()

    # Mode values are cached per point set; the cache is not shipped with the field.
    def __getstate__(self):
        state = self.__dict__.copy()
        state["_cache"] = ()
        return state

    @property
    def spec(self) -> FieldSpec:
        return self._spec

    @property
    def name(self) -> str:
        return self._spec.name

    @property
    def targets(self) -> list[str]:
        return self._spec.targets

    @property
    def n_modes(self) -> int:
        return self.basis.n_modes

    @property
    def captured_fraction(self) -> float:
        return self.basis.captured_fraction

    @property
    def amplitude(self) -> float:
        return self._spec.amplitude

    @property
    def warning(self) -> str | None:
        w = self.basis.warning
        return None if w is None else f"field '{self.name}': {w}"

    def modes_at(self, points) -> np.ndarray:
        """``basis.modes_at(points)``, cached (read-only) for the last few point sets."""
        p = np.asarray(points, dtype=float)
        cached = self._cached(p)
        if cached is not None:
            return cached
        value = self.basis.modes_at(p)
        self._remember(p, value)
        return value

    def _cached(self, p: np.ndarray):
        for key, value in self._cache:
            if key.shape == p.shape and np.array_equal(key, p):
                return value
        return None

    def _remember(self, p: np.ndarray, value: np.ndarray) -> None:
        value.setflags(write=False)
        if value.size <= _CACHE_ENTRIES:
            # Replace, never mutate: a thread reading the old tuple stays consistent.
            self._cache = ((p.copy(), value),) + self._cache[:_CACHE_SLOTS - 1]

    def _delta(self, g: np.ndarray, points) -> np.ndarray:
        p = np.asarray(points, dtype=float)
        cached = self._cached(p)
        if cached is not None:
            return cached @ g
        if p.shape[0] * self.n_modes <= _CACHE_ENTRIES:
            return self.modes_at(p) @ g
        return self.basis.field_at(p, g)      # too large to keep: O(points × nodes)

    def _germs(self, germs) -> np.ndarray:
        g = np.asarray(germs, dtype=float)
        if g.shape != (self.n_modes,):
            raise ValueError(f"field '{self.name}' has {self.n_modes} modes, got germs of "
                             f"shape {g.shape}")
        if not np.all(np.isfinite(g)):
            raise ValueError(f"field '{self.name}': germs must be finite")
        return g

    def perturbation(self, germs, points) -> np.ndarray:
        """δ(x) = Σ_j sqrt(λ_j) φ_j(x) ξ_j at ``points``, shape (n,)."""
        return self._delta(self._germs(germs), points)

    def realize(self, mean, germs, points, lower: float = -np.inf,
                upper: float = np.inf) -> tuple[np.ndarray, int]:
        """Field values mean · (1 + amplitude · δ(x)) at ``points``, and how many were clipped.

        Values at or beyond ``lower``/``upper`` are set to lower + 1e-3·|mean| (upper -
        1e-3·|mean|); never NaN, never <= lower. With amplitude 0 the values are ``mean``
        exactly (no clipping: the deterministic solver is reproduced bit for bit).
        """
        lower, upper = float(lower), float(upper)
        if not lower < upper:
            raise ValueError(f"lower ({lower:g}) must be below upper ({upper:g})")
        g = self._germs(germs)
        n = self.basis._points(points).shape[0]
        mean = np.asarray(mean, dtype=float)
        try:
            mean = np.broadcast_to(mean, (n,))
        except ValueError:
            raise ValueError(f"field '{self.name}': mean of shape {mean.shape} does not "
                             f"broadcast to the {n} points") from None
        if not np.all(np.isfinite(mean)):
            raise ValueError(f"field '{self.name}': mean must be finite")
        if self.amplitude == 0:
            return mean.copy(), 0
        values = mean * (1.0 + self.amplitude * self._delta(g, points))
        below, above = values <= lower, values >= upper
        n_clipped = int(np.count_nonzero(below | above))
        if n_clipped:
            margin = CLIP_MARGIN * np.abs(mean)
            lo_val = np.maximum(lower + margin, np.nextafter(lower, np.inf))
            hi_val = np.minimum(upper - margin, np.nextafter(upper, -np.inf))
            if math.isfinite(lower) and math.isfinite(upper):
                mid = 0.5 * (lower + upper)
                lo_val, hi_val = np.minimum(lo_val, mid), np.maximum(hi_val, mid)
            values = np.where(below, lo_val, np.where(above, hi_val, values))
        return values, n_clipped

    def __repr__(self) -> str:
        return (f"RandomField({self.name!r} -> {', '.join(self.targets)}, {self.basis!r}, "
                f"amplitude={self.amplitude:g})")


# --------------------------------------------------------------------------- one realization
class FieldSample(Mapping):
    """The fields of one realization, by driven parameter name.

    ``sample["bar.E"]`` is the RandomField driving ``bar.E``; ``sample.values("bar.E",
    points, mean=E)`` its values there. ``clipped[parameter]`` counts the values clipped so
    far (summed over calls).
    """

    def __init__(self, fields: list[RandomField], germs: dict):
        self._fields: dict[str, RandomField] = {}
        self.germs: dict[str, np.ndarray] = {}
        for f in fields:
            if f.name in self.germs:
                raise ValueError(f"field '{f.name}' is given twice")
            if f.name not in germs:
                raise ValueError(f"no germs for field '{f.name}'")
            self.germs[f.name] = f._germs(germs[f.name])
            for p in f.targets:
                if p in self._fields:
                    raise ValueError(f"parameter '{p}' is driven by fields "
                                     f"'{self._fields[p].name}' and '{f.name}'")
                self._fields[p] = f
        self.clipped: dict[str, int] = {p: 0 for p in self._fields}
        #: the last values handed out per parameter, for fields with ``store_values``
        self.evaluated: dict[str, np.ndarray] = {}

    @classmethod
    def from_design(cls, fields: list[RandomField], design, realization: int) -> "FieldSample":
        """The sample of realization ``realization`` (an index) of a kl-weibull design."""
        return cls(fields, {f.name: np.asarray(design[germ_variable(f.name)].values[realization])
                            for f in fields})

    def __getitem__(self, parameter: str) -> RandomField:
        return self._fields[parameter]

    def __iter__(self):
        return iter(self._fields)

    def __len__(self) -> int:
        return len(self._fields)

    def values(self, parameter: str, points, mean, lower: float = -np.inf,
               upper: float = np.inf) -> np.ndarray:
        """Values of the field driving ``parameter`` at ``points`` around ``mean``."""
        try:
            field = self._fields[parameter]
        except KeyError:
            raise KeyError(f"no random field drives '{parameter}' "
                           f"(driven: {', '.join(self._fields) or 'none'})") from None
        values, n_clipped = field.realize(mean, self.germs[field.name], points, lower, upper)
        self.clipped[parameter] += n_clipped
        if field.spec.store_values:
            self.evaluated[parameter] = np.asarray(values, dtype=float).reshape(-1)
        return values

    def __repr__(self) -> str:
        return f"FieldSample({', '.join(self._fields)})"


def germ_variable(field_name: str) -> str:
    """Name of the design variable holding a field's KL germs (netCDF-safe)."""
    return GERM_PREFIX + re.sub(r"[^0-9A-Za-z_]", "_", field_name)


def field_value_variable(parameter: str) -> str:
    """Name of the runs variable holding a stored field's values for ``parameter``."""
    return FIELD_PREFIX + re.sub(r"[^0-9A-Za-z_]", "_", parameter)


def germ_seed(seed: np.random.SeedSequence, realization: int,
              field_index: int) -> np.random.SeedSequence:
    """The seed of the germs of field ``field_index`` in realization ``realization``.

    Derived from the study seed and the two indices alone, so realization i draws the same
    germs whatever the design size, and the stream is distinct from the executor's
    per-realization seeds (spawn keys of another length).
    """
    realization, field_index = int(realization), int(field_index)
    if realization < 0 or field_index < 0:
        raise ValueError("realization and field_index must be >= 0")
    return np.random.SeedSequence(seed.entropy,
                                  spawn_key=(*seed.spawn_key, 7, realization, field_index))
