"""Random fields: KL eigenpairs (analytic and Nyström) against Ghanem & Spanos' exact values,
orthonormality, Mercer sums, sample covariances, symmetric-Weibull germs, truncation, extreme
correlation lengths, 2-D fields, realization/clipping, FieldSample, pickling and seeding.

Statistical checks use fixed seeds and a tolerance of 5 standard errors estimated from the
sample itself (a false alarm has probability ~1e-6 per check for a correct implementation).
"""

from __future__ import annotations

import math
import pickle
import re
from pathlib import Path

import numpy as np
import pydantic
import pytest
from scipy import stats

from uqflow.fields import (_RELATIVE_EIGENVALUE_FLOOR, FieldSample, FieldSpec, GermSpec,
                           KLBasis, RandomField, germ_seed)

CASES = [("a0_5_b1", 0.5, 1.0), ("a1_b1", 1.0, 1.0), ("a0_5_b0_1", 0.5, 0.1)]
# The reference values are rounded to 6 decimals: an exact eigenvalue is within 5e-7 of them.
REF_ROUNDING = 5e-7
EPS = float(np.finfo(float).eps)


def interval(a):
    return np.array([-a, a])


def reassociation_bound(basis: KLBasis, germs: np.ndarray) -> float:
    """Bound on two evaluations of δ(x) = Σ_j sqrt(λ_j) φ_j(x) g_j that sum in different orders.

    Each is a sum of M mode terms, and on a Nyström basis each term is itself an extension
    sum over n nodes whose terms are at most |D|·max|φ_j(nodes)|·|g_j|/sqrt(λ_j) (kernel ≤ 1,
    weights sum to |D|): by Higham's γ bound each order errs by ≤ (n + M)·eps times the sum
    of those magnitudes.
    """
    g = np.abs(np.asarray(germs, dtype=float))
    if basis.method != "nystrom":
        return 2 * basis.n_modes * EPS * float(g @ np.sqrt(basis.eigenvalues)) * 2.0
    nodal = np.abs(basis.eigenfunctions(basis.nodes)).max(axis=0)
    term = basis.total_variance * nodal / np.sqrt(basis.eigenvalues)
    return 2 * (basis.nodes.shape[0] + basis.n_modes) * EPS * float(g @ term)


def mean_with_stderr(y):
    """Sample mean over axis 0 and its standard error."""
    return y.mean(axis=0), y.std(axis=0, ddof=1) / math.sqrt(y.shape[0])


# --------------------------------------------------------------------------- eigenvalues
@pytest.mark.parametrize("key,a,b", CASES)
def test_analytic_eigenvalues_match_ghanem_spanos(reference, key, a, b):
    ref = np.array(reference["kl_exponential"][key])
    basis = KLBasis.build("exponential", b, interval(a), modes=6)
    assert basis.method == "analytic"
    # 1e-6 relative on top of the reference's own rounding.
    np.testing.assert_allclose(basis.eigenvalues, ref, rtol=1e-6, atol=REF_ROUNDING)


@pytest.mark.parametrize("key,a,b", CASES)
def test_nystrom_eigenvalues_match_reference_and_analytic(reference, key, a, b):
    ref = np.array(reference["kl_exponential"][key])
    num = KLBasis.build("exponential", b, interval(a), modes=6, method="nystrom")
    assert num.method == "nystrom" and num.nodes.shape == (400, 1)
    np.testing.assert_allclose(num.eigenvalues, ref, rtol=1e-4)
    # Against the exact roots the corrected Nyström scheme is far better (measured ~5e-8).
    exact = KLBasis.build("exponential", b, interval(a), modes=6).eigenvalues
    np.testing.assert_allclose(num.eigenvalues, exact, rtol=1e-6)


def test_nystrom_converges_fast_for_the_exponential_kernel():
    """Singularity subtraction: the error falls ~16x per doubling of the grid (N^-4)."""
    exact = KLBasis.build("exponential", 1.0, interval(0.5), modes=6).eigenvalues
    err = [np.max(np.abs(KLBasis.build("exponential", 1.0, interval(0.5), modes=6,
                                       method="nystrom", quadrature_points=q).eigenvalues
                         / exact - 1)) for q in (50, 100, 200)]
    assert err[1] < err[0] / 10 and err[2] < err[1] / 10


def test_analytic_eigenvalue_sum_approaches_domain_measure():
    a, b = 0.5, 1.0
    basis = KLBasis.build("exponential", b, interval(a), modes=400)
    total = basis.eigenvalues.sum()
    assert basis.total_variance == 2 * a
    # Tail beyond M modes: λ ≈ 2c/ω², ω_j ≈ jπ/(2a)  ->  Σ_{j>M} ≈ 8 c a² / (π² M).
    tail = 8 * (1 / b) * a**2 / (math.pi**2 * 400)
    assert 0 < 2 * a - total < 1.2 * tail
    assert abs(2 * a - total - tail) < 0.1 * tail
    assert basis.captured_fraction == pytest.approx(total / (2 * a))


def test_nystrom_trace_is_the_domain_measure():
    # 1-D (corrected scheme): the eigenvalues sum to the measure up to the unresolved tail.
    basis = KLBasis.build("exponential", 1.0, interval(0.5), modes=400, method="nystrom")
    assert 0 < 1.0 - basis.eigenvalues.sum() < 1e-3
    # 2-D (plain Nyström on the points): the trace is exactly the box area.
    pts = np.random.default_rng(3).random((150, 2)) * [2.0, 1.0]
    b2 = KLBasis.build("exponential", 0.5, pts, modes=150)
    assert b2.total_variance == pytest.approx(np.prod(pts.max(0) - pts.min(0)))
    # eigh returns each eigenvalue within n·eps·‖S‖ (‖S‖ ≤ trace): the sum within n²·eps
    assert b2.eigenvalues.sum() == pytest.approx(b2.total_variance, rel=pts.shape[0]**2 * EPS)


def test_eigenvalues_descend_and_are_positive():
    for method in ("analytic", "nystrom"):
        lam = KLBasis.build("exponential", 0.3, interval(1.0), modes=50, method=method).eigenvalues
        assert np.all(lam > 0) and np.all(np.diff(lam) < 0)


# --------------------------------------------------------------------------- eigenfunctions
def gram_error_bound(eigenvalues: np.ndarray, nodes: int) -> np.ndarray:
    """Bound on |G_jl - δ_jl| for Nyström modes evaluated through the extension at the nodes.

    There φ_j = S v_j / λ_j (S the symmetrised n×n matrix, v_j its computed eigenvector), so
    G_jl - δ_jl = (v_j·v_l - δ_jl) + v_j·r_l / λ_l + v_l·r_j / λ_j with r = S v - λ v. A
    backward-stable symmetric eigensolver keeps both V^T V - I and ‖r‖ / ‖S‖ below n·eps
    (taking p(n) = n, the a-priori worst case of the rounding in the products of length n;
    the extension's own sums are of that length too), and ‖S‖ = λ_1. The quadrature weights
    cancel in G (w_i·(v_i/√w_i)², a few roundings each), so their conditioning does not
    enter; neither does the eigenvalue gap, which bounds how far v_j is from the exact
    eigenvector, not how orthogonal the computed ones are.
    """
    ratio = eigenvalues[0] / eigenvalues
    return nodes * np.finfo(float).eps * (1.0 + ratio[:, None] + ratio[None, :])


def test_nystrom_eigenfunctions_orthonormal_under_the_quadrature():
    # Evaluated through the public Nyström extension at the nodes: the error of mode j grows
    # as eps·λ_1/λ_j, so the smooth kernel (λ_j down to 1e-9 λ_1) has a looser bound on its
    # last modes than on its first; the bound is per entry.
    for kernel in ("exponential", "squared_exponential"):
        basis = KLBasis.build(kernel, 0.4, interval(0.5), modes=20, method="nystrom")
        phi = basis.eigenfunctions(basis.nodes)
        gram = phi.T @ (basis.weights[:, None] * phi)
        bound = gram_error_bound(basis.eigenvalues, basis.nodes.shape[0])
        excess = np.abs(gram - np.eye(basis.n_modes)) - bound
        assert np.all(excess <= 0), (kernel, np.unravel_index(np.argmax(excess), excess.shape),
                                     excess.max())


def test_analytic_eigenfunctions_orthonormal():
    basis = KLBasis.build("exponential", 0.3, np.array([2.0, 5.0]), modes=12)
    t, w = np.polynomial.legendre.leggauss(400)
    x, w = 3.5 + 1.5 * t, 1.5 * w
    phi = basis.eigenfunctions(x)
    # Bound: 400-term sums (400·eps, |φ_j φ_l| weights summing to ≤ 1); cos/sin of arguments
    # up to ω_max·a lose that many eps (twice, a product); the roots t = ω a are bracketed to
    # 1e-15 (1 + t) (brentq's xtol, rtol), which moves the inner products by as much. The
    # 400-point Gauss rule is exact far below that for these analytic integrands.
    t_max = float(basis._omega.max()) * 1.5
    bound = (x.size + 2 * (t_max + 2)) * EPS + 2e-15 * (1 + t_max)
    np.testing.assert_allclose(phi.T @ (w[:, None] * phi), np.eye(12), atol=bound)


def test_analytic_and_nystrom_eigenfunctions_agree():
    pts = np.array([1.0, 3.0])   # off-centre domain: the analytic modes are shifted
    exact = KLBasis.build("exponential", 0.7, pts, modes=8)
    num = KLBasis.build("exponential", 0.7, pts, modes=8, method="nystrom")
    x = np.linspace(1.0, 3.0, 37)
    fe, fn = exact.eigenfunctions(x), num.eigenfunctions(x)
    sign = np.sign(np.sum(fe * fn, axis=0))
    # Between the nodes the extension converges as N^-3 (measured 8e-6 at N = 400);
    # at the nodes as N^-4 (2.5e-7).
    np.testing.assert_allclose(fn * sign, fe, atol=2e-5)
    xn = num.nodes[:, 0]
    np.testing.assert_allclose(num.eigenfunctions(xn) * sign, exact.eigenfunctions(xn),
                               atol=1e-6)


def test_mercer_sum_gives_unit_pointwise_variance():
    """Σ λ_j φ_j(x)² -> C(x, x) = 1 (measure-normalised φ): checks the normalisation."""
    x = np.linspace(-0.5, 0.5, 41)
    for method in ("analytic", "nystrom"):
        basis = KLBasis.build("exponential", 1.0, interval(0.5), modes=400, method=method)
        var = np.sum(basis.modes_at(x) ** 2, axis=1)
        # Interior points: the 400-mode tail is ~5e-4 of the variance; ends lose more.
        assert np.all(np.abs(var[2:-2] - 1) < 2e-3), var
    smooth = KLBasis.build("squared_exponential", 0.3, interval(0.5), captured_variance=1.0)
    var = np.sum(smooth.modes_at(x) ** 2, axis=1)
    # Bound: the modes left out have λ ≤ floor·λ_1 each, and Σ_j φ_j² over all n discrete
    # modes is 1/w at a node (completeness of the eigenvectors): ≤ floor·λ_1 / min(w).
    bound = _RELATIVE_EIGENVALUE_FLOOR * smooth.eigenvalues[0] / smooth.weights.min()
    np.testing.assert_allclose(var, 1.0, atol=bound)


def test_modes_reproduce_the_kernel():
    """Σ_j λ_j φ_j(x) φ_j(y) ≈ exp(-|x - y| / b) (Mercer)."""
    x = np.linspace(-0.4, 0.4, 9)
    basis = KLBasis.build("exponential", 0.5, interval(0.5), modes=400)
    m = basis.modes_at(x)
    exact = np.exp(-np.abs(x[:, None] - x[None, :]) / 0.5)
    np.testing.assert_allclose(m @ m.T, exact, atol=3e-3)


# --------------------------------------------------------------------------- sample covariance
@pytest.mark.parametrize("germ", [GermSpec(kind="gaussian"), GermSpec(),
                                  GermSpec(scale=0.7, shape=1.3)])
def test_sample_covariance_approaches_truncated_kernel(germ):
    """5,000 realizations at 6 points: every entry of E[δ(x)δ(y)] / E[ξ²] within 5 standard
    errors (se ≈ sqrt(2/5000) ≈ 0.02 for unit variances) of Σ λ φ(x) φ(y)."""
    field = RandomField(FieldSpec(name="E", correlation_length=0.3, germ=germ),
                        np.linspace(0.0, 1.0, 101))
    x = np.array([0.0, 0.1, 0.33, 0.5, 0.8, 1.0])
    rng = np.random.default_rng(42)
    germs = germ.draw((5000, field.n_modes), rng)
    delta = germs @ field.modes_at(x).T
    prod = (delta[:, :, None] * delta[:, None, :]).reshape(5000, -1) / germ.second_moment()
    est, se = mean_with_stderr(prod)
    m = field.modes_at(x)
    truncated = (m @ m.T).ravel()
    assert np.all(np.abs(est - truncated) <= 5 * se), np.max(np.abs(est - truncated) / se)
    # The truncated kernel itself is within the 5 % of variance left out of the exact one.
    exact = np.exp(-np.abs(x[:, None] - x[None, :]) / 0.3).ravel()
    assert np.all(np.abs(truncated - exact) < 0.1)
    # perturbation() is the same sum.
    # the same sum in another order: reassociation_bound (Higham's γ)
    np.testing.assert_allclose(field.perturbation(germs[0], x), delta[0], rtol=0,
                               atol=reassociation_bound(field.basis, germs[0]))


def test_two_dimensional_squared_exponential_on_scattered_points():
    rng = np.random.default_rng(7)
    pts = rng.random((400, 2)) * [2.0, 1.0]
    spec = FieldSpec(name="plate.E", kernel="squared_exponential", correlation_length=0.4,
                     germ=GermSpec(kind="gaussian"))
    field = RandomField(spec, pts)
    assert field.basis.method == "nystrom" and field.captured_fraction >= 0.95
    probe = pts[[0, 1, 2, 3, 4]]
    m = field.modes_at(probe)
    germs = spec.germ.draw((5000, field.n_modes), rng)
    delta = germs @ m.T
    est, se = mean_with_stderr((delta[:, :, None] * delta[:, None, :]).reshape(5000, -1))
    assert np.all(np.abs(est - (m @ m.T).ravel()) <= 5 * se)
    # At the nodes, the truncated covariance is the kernel minus a small remainder.
    r2 = np.sum((probe[:, None] - probe[None]) ** 2, axis=-1)
    assert np.max(np.abs(m @ m.T - np.exp(-r2 / 0.4**2))) < 0.15
    # Off the nodes (Nyström extension) the field is smooth and finite.
    off = rng.random((50, 2)) * [2.0, 1.0]
    assert np.all(np.isfinite(field.perturbation(germs[0], off)))


def test_two_dimensional_eigenfunctions_orthonormal_and_order_free():
    rng = np.random.default_rng(8)
    pts = rng.random((200, 2))
    basis = KLBasis.build("exponential", 0.3, pts, modes=30)
    phi = basis.eigenfunctions(basis.nodes)
    gram = phi.T @ (basis.weights[:, None] * phi)
    # per entry: gram_error_bound (n·eps·(1 + λ_1/λ_j + λ_1/λ_l), plain Nyström as in 1-D)
    bound = gram_error_bound(basis.eigenvalues, basis.nodes.shape[0])
    assert np.all(np.abs(gram - np.eye(30)) <= bound)
    shuffled = KLBasis.build("exponential", 0.3, pts[rng.permutation(200)], modes=30)
    np.testing.assert_array_equal(shuffled.nodes, basis.nodes)
    # Same nodes, same matrix: the modes differ by at most eigh's and the extension's
    # rounding, n·eps·λ_1/λ_j relative to mode j (as in gram_error_bound)
    ratio = basis.eigenvalues[0] / basis.eigenvalues
    scale = np.abs(basis.modes_at(pts)).max(axis=0)
    assert np.all(np.abs(shuffled.modes_at(pts) - basis.modes_at(pts))
                  <= basis.nodes.shape[0] * EPS * (1 + ratio) * scale)


def test_many_points_in_two_dimensions_use_cell_representatives():
    rng = np.random.default_rng(9)
    pts = rng.random((3000, 2)) * [3.0, 1.0]
    basis = KLBasis.build("squared_exponential", 0.5, pts, quadrature_points=40)
    assert basis.nodes.shape[0] <= 5 * 40
    assert basis.nodes.shape[0] > 150          # nearly every cell is occupied
    var = np.sum(basis.modes_at(pts) ** 2, axis=1)
    assert np.all(np.isfinite(var)) and 0.8 < var.mean() < 1.0


def test_points_on_a_line_in_two_dimensions_use_the_one_dimensional_basis():
    x = np.linspace(0.0, 2.0, 30)
    flat = KLBasis.build("exponential", 0.5, np.column_stack([x, np.full(30, 0.25)]))
    line = KLBasis.build("exponential", 0.5, x)
    assert flat.method == "analytic"
    np.testing.assert_allclose(flat.eigenvalues, line.eigenvalues)
    np.testing.assert_allclose(flat.modes_at(np.column_stack([x, np.zeros(30)])),
                               line.modes_at(x))


def test_coincident_points_make_one_random_variable():
    basis = KLBasis.build("exponential", 1.0, np.full((5, 2), 3.0))
    assert basis.method == "point" and basis.n_modes == 1 and basis.captured_fraction == 1
    np.testing.assert_array_equal(basis.modes_at(np.full((3, 2), 3.0)), np.ones((3, 1)))


# --------------------------------------------------------------------------- germs
@pytest.mark.parametrize("scale,shape", [(1.0, 2.0), (0.5, 0.8), (2.0, 3.5)])
def test_symmetric_weibull_germs(scale, shape):
    germ = GermSpec(scale=scale, shape=shape)
    xi = germ.draw(20000, np.random.default_rng(11))
    assert germ.second_moment() == pytest.approx(scale**2 * math.gamma(1 + 2 / shape))
    m, se = mean_with_stderr(xi)
    assert abs(m) < 5 * se                                      # mean 0
    m2, se2 = mean_with_stderr(xi**2)
    assert abs(m2 - germ.second_moment()) < 5 * se2
    # |ξ| is Weibull(scale, shape); the sign is a fair coin.
    assert stats.kstest(np.abs(xi), "weibull_min", args=(shape, 0, scale)).pvalue > 1e-3
    assert stats.binomtest(int(np.sum(xi > 0)), xi.size, 0.5).pvalue > 1e-3
    assert set(np.unique(np.sign(xi))) == {-1.0, 1.0}


def test_seed_germ_has_unit_second_moment_and_gaussian_germs():
    assert GermSpec().second_moment() == pytest.approx(1.0)          # Weibull(1, 2): Γ(2) = 1
    assert GermSpec(kind="gaussian", scale=3.0).second_moment() == 1.0
    z = GermSpec(kind="gaussian").draw(20000, np.random.default_rng(1))
    assert stats.kstest(z, "norm").pvalue > 1e-3


def test_germ_spec_validation():
    for bad in ({"scale": 0}, {"shape": -1}, {"kind": "uniform"}, {"scale": float("nan")},
                {"mean": 1}):
        with pytest.raises(pydantic.ValidationError):
            GermSpec(**bad)


# --------------------------------------------------------------------------- field spec
def test_field_spec_defaults_and_forms():
    s = FieldSpec(name="bar.E", correlation_length=0.1)
    assert s.targets == ["bar.E"] and s.captured_variance == 0.95 and s.modes is None
    assert s.divisor == 10 and s.cv is None and s.amplitude == pytest.approx(0.1)
    assert s.kernel == "exponential" and s.germ.kind == "symmetric-weibull"
    assert s.quadrature_points == 400 and s.store_values is False
    c = FieldSpec(name="f", parameters=["a", "b"], correlation_length=1, cv=0.1,
                  germ={"scale": 1.0, "shape": 1.0}, modes=5)
    assert c.targets == ["a", "b"] and c.captured_variance is None
    # C.V. form: amplitude · sqrt(E[ξ²]) = cv (Weibull shape 1: E[W²] = 2).
    assert c.amplitude * math.sqrt(2.0) == pytest.approx(0.1)
    assert FieldSpec.model_validate(s.model_dump()) == s


@pytest.mark.parametrize("bad", [
    {"modes": 3, "captured_variance": 0.9}, {"divisor": 5, "cv": 0.1},
    {"correlation_length": 0}, {"captured_variance": 1.5}, {"captured_variance": 0},
    {"modes": 0}, {"divisor": 0}, {"cv": -0.1}, {"quadrature_points": 4},
    {"kernel": "matern"}, {"parameters": []}, {"parameters": ["a", "a"]}, {"color": "red"},
])
def test_field_spec_rejects(bad):
    raw = {"name": "f", "correlation_length": 0.5, **bad}
    with pytest.raises(pydantic.ValidationError):
        FieldSpec(**raw)


# --------------------------------------------------------------------------- truncation
@pytest.mark.parametrize("kernel", ["exponential", "squared_exponential"])
@pytest.mark.parametrize("fraction", [0.5, 0.8, 0.95, 0.99])
def test_truncation_by_captured_variance(kernel, fraction):
    basis = KLBasis.build(kernel, 0.2, np.linspace(0, 1, 11), captured_variance=fraction)
    assert basis.captured_fraction >= fraction and not basis.capped
    fewer = basis.eigenvalues[:-1].sum() / basis.total_variance
    assert fewer < fraction                                      # the fewest modes that do it
    assert basis.warning is None


def test_truncation_by_mode_count():
    basis = KLBasis.build("exponential", 0.2, interval(0.5), modes=7)
    assert basis.n_modes == 7 and basis.modes_at(np.zeros(3)).shape == (3, 7)
    assert basis.captured_fraction == pytest.approx(basis.eigenvalues.sum())
    capped = KLBasis.build("squared_exponential", 2.0, interval(0.5), modes=300)
    assert capped.n_modes < 300 and capped.capped and "requested" in capped.warning


@pytest.mark.numerics
@pytest.mark.parametrize("kernel", ["exponential", "squared_exponential"])
@pytest.mark.parametrize("dim", [1, 2])
def test_extreme_correlation_lengths(kernel, dim):
    rng = np.random.default_rng(5)
    pts = np.linspace(0, 1, 60)[:, None] if dim == 1 else rng.random((300, 2))
    short = RandomField(FieldSpec(name="E", kernel=kernel, correlation_length=1e-4,
                                  quadrature_points=60), pts)
    if dim == 1:
        # Far too many modes would be needed: truncation stops at what exists, and says so.
        assert short.basis.capped and short.warning is not None
        assert short.n_modes <= 60 and short.captured_fraction < 0.95
    else:
        # At the 300 points (the Nyström nodes) the field is white noise: 95 % of its
        # variance takes 95 % of the modes. 285 equal eigenvalues are 0.95 exactly, so the
        # rounding of eigh (any BLAS) and the 300-term sums decides the side: the code takes a
        # sum within 1e-12 of its target (≫ 300 eps), and so does this check.
        assert short.n_modes >= 0.94 * 300 and short.captured_fraction >= 0.95 * (1 - 1e-12)
    germs = short.spec.germ.draw(short.n_modes, rng)
    values, _ = short.realize(2.0, germs, pts)
    assert np.all(np.isfinite(values))
    # Very long correlation: one mode holds about everything.
    long = RandomField(FieldSpec(name="E", kernel=kernel, correlation_length=100.0), pts)
    assert long.n_modes == 1 and long.captured_fraction > 0.99 and long.warning is None
    v = np.sum(long.modes_at(pts) ** 2, axis=1)
    assert np.all(v > 0.98) and np.all(v < 1.0 + 1e-9)


# --------------------------------------------------------------------------- realize
def test_zero_amplitude_reproduces_the_mean_bitwise():
    pts = np.linspace(0, 1, 25)
    field = RandomField(FieldSpec(name="E", correlation_length=0.2, cv=0.0), pts)
    germs = field.spec.germ.draw(field.n_modes, np.random.default_rng(0))
    mean = 210e9 / 3                                       # not a round number
    values, n = field.realize(mean, germs, pts, lower=0.0)
    assert n == 0 and values.dtype == float and values.shape == (25,)
    assert np.array_equal(values, np.full(25, mean))
    arr = np.linspace(1.0, 2.0, 25) / 7
    values, _ = field.realize(arr, germs, pts)
    assert np.array_equal(values, arr) and values is not arr


def test_realize_is_mean_times_one_plus_amplitude_delta():
    pts = np.linspace(0, 1, 25)
    field = RandomField(FieldSpec(name="E", correlation_length=0.2, divisor=4), pts)
    germs = field.spec.germ.draw(field.n_modes, np.random.default_rng(0))
    values, n = field.realize(3.0, germs, pts)
    np.testing.assert_allclose(values, 3.0 * (1 + 0.25 * field.perturbation(germs, pts)))
    assert n == 0
    with pytest.raises(ValueError):
        field.realize(3.0, germs[:-1], pts)
    with pytest.raises(ValueError):
        field.realize(np.ones(3), germs, pts)
    with pytest.raises(ValueError):
        field.realize(3.0, germs, pts, lower=1.0, upper=1.0)


def test_clipping_keeps_values_physical():
    pts = np.linspace(0, 1, 200)
    spec = FieldSpec(name="E", correlation_length=0.05, divisor=2,
                     germ=GermSpec(scale=1.0, shape=0.8))
    field = RandomField(spec, pts)
    rng = np.random.default_rng(2)
    total = crossing = 0
    for _ in range(20):
        germs = spec.germ.draw(field.n_modes, rng)
        raw = 5.0 * (1 + field.amplitude * field.perturbation(germs, pts))
        values, n = field.realize(5.0, germs, pts, lower=0.0)
        assert n == np.count_nonzero(raw <= 0)
        assert np.all(np.isfinite(values)) and np.all(values > 0)
        np.testing.assert_array_equal(values[raw <= 0], 5.0e-3)
        np.testing.assert_array_equal(values[raw > 0], raw[raw > 0])
        total += n
        crossing += n > 0
    # docs/fields.md: divisor 2 with shape 0.8 "crosses zero in most realizations"
    assert crossing > 10
    # Upper bounds the same way.
    germs = spec.germ.draw(field.n_modes, rng)
    values, n = field.realize(5.0, germs, pts, lower=0.0, upper=6.0)
    assert np.all((values > 0) & (values < 6.0)) and n > 0


def test_clipping_never_reaches_the_bound():
    field = RandomField(FieldSpec(name="E", correlation_length=0.5, divisor=0.01),
                        np.linspace(0, 1, 10))
    germs = np.full(field.n_modes, -3.0)
    for mean, lower in ((1e-300, 0.0), (1.0, 1e10), (0.0, -1.0)):
        values, _ = field.realize(mean, germs, np.linspace(0, 1, 10), lower=lower)
        assert np.all(values > lower) and np.all(np.isfinite(values))


# --------------------------------------------------------------------------- FieldSample
def make_fields():
    pts = np.linspace(0, 1, 50)
    e = RandomField(FieldSpec(name="bar.E", correlation_length=0.2, divisor=2,
                              germ=GermSpec(shape=0.8)), pts)
    r = RandomField(FieldSpec(name="dens", parameters=["bar.rho", "bar.rho0"],
                              correlation_length=0.5, cv=0.05), pts)
    return pts, [e, r]


def test_field_sample_mapping_and_values():
    pts, fields = make_fields()
    rng = np.random.default_rng(4)
    germs = {f.name: f.spec.germ.draw(f.n_modes, rng) for f in fields}
    sample = FieldSample(fields, germs)
    assert list(sample) == ["bar.E", "bar.rho", "bar.rho0"] and len(sample) == 3
    assert sample["bar.rho"] is fields[1] and sample["bar.rho0"] is fields[1]
    assert "bar.E" in sample and "dens" not in sample
    assert sample.clipped == {"bar.E": 0, "bar.rho": 0, "bar.rho0": 0}
    mid = 0.5 * (pts[1:] + pts[:-1])
    v = sample.values("bar.E", mid, mean=2e11, lower=0.0)
    expect, n = fields[0].realize(2e11, germs["bar.E"], mid, lower=0.0)
    np.testing.assert_array_equal(v, expect)
    assert sample.clipped["bar.E"] == n
    sample.values("bar.E", mid, mean=2e11, lower=0.0)
    assert sample.clipped["bar.E"] == 2 * n                     # summed over calls
    # Both parameters of one field share its germs.
    np.testing.assert_array_equal(sample.values("bar.rho", pts[:, None], 7800.0),
                                  sample.values("bar.rho0", pts, 7800.0))
    with pytest.raises(KeyError, match="no random field drives"):
        sample.values("bar.nu", pts, 0.3)


def test_field_sample_clipped_counts_are_recorded():
    pts, fields = make_fields()
    rng = np.random.default_rng(0)
    counts = 0
    for _ in range(30):
        sample = FieldSample(fields, {f.name: f.spec.germ.draw(f.n_modes, rng) for f in fields})
        v = sample.values("bar.E", pts, mean=1.0, lower=0.0)
        assert np.all(v > 0)
        counts += sample.clipped["bar.E"]
    assert counts > 0


def test_field_sample_rejects_bad_input():
    pts, fields = make_fields()
    germs = {f.name: np.zeros(f.n_modes) for f in fields}
    with pytest.raises(ValueError, match="no germs"):
        FieldSample(fields, {"bar.E": germs["bar.E"]})
    with pytest.raises(ValueError, match="modes"):
        FieldSample(fields, {**germs, "bar.E": np.zeros(fields[0].n_modes + 1)})
    twin = RandomField(FieldSpec(name="other", parameters=["bar.E"], correlation_length=1),
                       pts)
    with pytest.raises(ValueError, match="driven by"):
        FieldSample([fields[0], twin], {**germs, "other": np.zeros(twin.n_modes)})


def test_pickle_round_trip():
    pts, fields = make_fields()
    rng = np.random.default_rng(6)
    germs = {f.name: f.spec.germ.draw(f.n_modes, rng) for f in fields}
    before = [f.realize(1.0, germs[f.name], pts)[0] for f in fields]   # fills the caches
    for f, b in zip(pickle.loads(pickle.dumps(fields)), before):
        assert f._cache == ()
        np.testing.assert_array_equal(f.realize(1.0, germs[f.name], pts)[0], b)
        assert f.spec == fields[0].spec or f.spec == fields[1].spec
    sample = pickle.loads(pickle.dumps(FieldSample(fields, germs)))
    np.testing.assert_array_equal(sample.values("bar.E", pts, 1.0), before[0])
    for basis_points in (np.random.default_rng(1).random((80, 2)), pts):
        field = RandomField(FieldSpec(name="x", correlation_length=0.3), basis_points)
        copy = pickle.loads(pickle.dumps(field))
        np.testing.assert_array_equal(copy.modes_at(basis_points), field.modes_at(basis_points))


def test_modes_at_point_shapes():
    basis = KLBasis.build("exponential", 0.3, np.linspace(0, 1, 5)[:, None], modes=4)
    x = np.linspace(0, 1, 7)
    np.testing.assert_array_equal(basis.modes_at(x), basis.modes_at(x[:, None]))
    with pytest.raises(ValueError):
        basis.modes_at(np.zeros((3, 2)))
    with pytest.raises(ValueError):
        KLBasis.build("exponential", 0.3, np.zeros((4, 3)))
    with pytest.raises(ValueError):
        KLBasis.build("exponential", 0.3, np.array([0.0, np.nan]))
    with pytest.raises(ValueError):
        KLBasis.build("squared_exponential", 0.3, x, method="analytic")


# --------------------------------------------------------------------------- seeding
def test_germ_seed_is_a_function_of_seed_and_indices():
    seed = np.random.SeedSequence(1234)
    draw = lambda s: GermSpec().draw(8, np.random.default_rng(s))  # noqa: E731
    np.testing.assert_array_equal(draw(germ_seed(seed, 3, 1)),
                                  draw(germ_seed(np.random.SeedSequence(1234), 3, 1)))
    assert not np.array_equal(draw(germ_seed(seed, 3, 1)), draw(germ_seed(seed, 4, 1)))
    assert not np.array_equal(draw(germ_seed(seed, 3, 1)), draw(germ_seed(seed, 3, 0)))
    assert not np.array_equal(draw(germ_seed(seed, 3, 1)),
                              draw(germ_seed(np.random.SeedSequence(1235), 3, 1)))
    s = germ_seed(seed, 3, 1)
    assert s.entropy == seed.entropy and s.spawn_key == (7, 3, 1)
    child = seed.spawn(1)[0]
    assert germ_seed(child, 0, 0).spawn_key == (*child.spawn_key, 7, 0, 0)
    # The seed object is not advanced.
    assert seed.n_children_spawned == 1
    with pytest.raises(ValueError):
        germ_seed(seed, -1, 0)


def test_field_at_matches_modes_and_large_point_sets_skip_the_cache(monkeypatch):
    rng = np.random.default_rng(12)
    for pts in (np.linspace(0, 1, 30), rng.random((120, 2))):
        for kernel in ("exponential", "squared_exponential"):
            basis = KLBasis.build(kernel, 0.3, pts, modes=10)
            g = rng.standard_normal(basis.n_modes)
            x = pts[::3] + 0.01              # off the nodes as well
            # two summation orders of the same extension: reassociation_bound
            np.testing.assert_allclose(basis.field_at(x, g), basis.modes_at(x) @ g,
                                       rtol=0, atol=reassociation_bound(basis, g))
    field = RandomField(FieldSpec(name="E", kernel="squared_exponential",
                                  correlation_length=0.3), rng.random((120, 2)))
    g = field.spec.germ.draw(field.n_modes, rng)
    x = rng.random((40, 2))
    small, _ = field.realize(1.0, g, x)
    import uqflow.fields as fields_module
    monkeypatch.setattr(fields_module, "_CACHE_ENTRIES", 10)
    fresh = RandomField(field.spec, field.basis.nodes)
    fresh.basis = field.basis
    large, _ = fresh.realize(1.0, g, x)
    assert fresh._cache == ()
    # cached modes against one extension per block: two summation orders of the same sum
    np.testing.assert_allclose(large, small, rtol=0,
                               atol=reassociation_bound(field.basis, g) * field.amplitude)


# --------------------------------------------------------------------------- docs/fields.md
FIELDS_DOC = Path(__file__).resolve().parent.parent / "docs" / "fields.md"
SUPERSCRIPT = str.maketrans("⁻⁰¹²³⁴⁵⁶⁷⁸⁹", "-0123456789")


def _shown(text: str) -> tuple[float, float]:
    """A number as the doc prints it ("0.738811", "1.3e-04", "2.5·10⁻⁷") and one unit in its
    last digit: two roundings of values that agree to within that unit can print so."""
    text = text.strip().translate(SUPERSCRIPT).replace("·10", "e")
    mantissa, _, exponent = text.partition("e")
    decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
    scale = 10.0 ** int(exponent) if exponent else 1.0
    return float(mantissa) * scale, 10.0 ** -decimals * scale


def _agrees(text: str, value: float) -> bool:
    shown, unit = _shown(text)
    return abs(shown - value) <= unit * (1 + 1e-9)


def _plain_nystrom(b: float, a: float, n: int, modes: int = 6) -> np.ndarray:
    """Gauss–Legendre Nyström without the singularity subtraction (the doc's comparison)."""
    t, w = np.polynomial.legendre.leggauss(n)
    x, w = a * t, a * w
    sw = np.sqrt(w)
    return np.linalg.eigvalsh(sw[:, None] * np.exp(-np.abs(x[:, None] - x) / b) * sw)[::-1][:modes]


def _rel(approx, exact):
    return np.abs(np.asarray(approx) / exact - 1)


@pytest.mark.slow
def test_accuracy_section_of_the_docs(reference):
    text = FIELDS_DOC.read_text(encoding="utf-8")
    section = text[text.index("## Accuracy"):]
    tables = re.findall(r"\*\*a = ([0-9.]+), b = ([0-9.]+)\*\* \(`(\w+)`\)\n\n\|[^\n]*\n\|[^\n]*\n"
                        r"((?:\|[^\n]*\n)+)", section)
    assert len(tables) == 3
    worst_rounding = 0.0
    for a, b, key, body in tables:
        a, b = float(a), float(b)
        ref = np.array(reference["kl_exponential"][key])
        exact = KLBasis.build("exponential", b, interval(a), modes=6).eigenvalues
        nys = KLBasis.build("exponential", b, interval(a), modes=6, method="nystrom").eigenvalues
        plain = _plain_nystrom(b, a, 400)
        worst_rounding = max(worst_rounding, np.abs(exact - ref).max())
        rows = [[c.strip() for c in line.split("|")[1:-1]] for line in body.splitlines()]
        assert [int(r[0]) for r in rows] == [1, 2, 3, 4, 5, 6]
        for j, (_, r_ref, r_exact, r_nys, r_rel, r_plain) in enumerate(rows):
            assert float(r_ref) == ref[j], (key, j)
            assert _agrees(r_exact, exact[j]) and _agrees(r_nys, nys[j]), (key, j)
            rel = _rel(nys[j], exact[j])
            assert rel < 1e-9 if r_rel == "< 1e-9" else _agrees(r_rel, rel), (key, j, rel)
            assert _agrees(r_plain, _rel(plain[j], exact[j])), (key, j)
    stated = re.search(r"≤ ([0-9.]+·10⁻[⁰¹²³⁴⁵⁶⁷⁸⁹]+) absolute", section).group(1)
    assert _agrees(stated, worst_rounding)

    convergence = re.search(r"\| N \| corrected Nyström \| plain Nyström \|\n\|[^\n]*\n"
                            r"((?:\|[^\n]*\n)+)", section).group(1)
    exact = KLBasis.build("exponential", 1.0, interval(0.5), modes=6).eigenvalues
    for line in convergence.splitlines():
        n, corrected, plain = [c.strip() for c in line.split("|")[1:-1]]
        got = KLBasis.build("exponential", 1.0, interval(0.5), modes=6, method="nystrom",
                            quadrature_points=int(n)).eigenvalues
        assert _agrees(corrected, _rel(got, exact).max()), n
        assert _agrees(plain, _rel(_plain_nystrom(1.0, 0.5, int(n)), exact).max()), n

    nodes_err, between_err = re.search(r"largest error is ([0-9.]+·10⁻[⁰¹²³⁴⁵⁶⁷⁸⁹]+) at the nodes and "
                                       r"([0-9.]+·10⁻[⁰¹²³⁴⁵⁶⁷⁸⁹]+) at 37", section).groups()
    pts = np.array([1.0, 3.0])
    exact_b, num = (KLBasis.build("exponential", 0.7, pts, modes=8, method=m)
                    for m in ("analytic", "nystrom"))
    x = np.linspace(1.0, 3.0, 37)
    sign = np.sign(np.sum(exact_b.eigenfunctions(x) * num.eigenfunctions(x), axis=0))
    xn = num.nodes[:, 0]
    assert _agrees(nodes_err, np.abs(num.eigenfunctions(xn) * sign
                                     - exact_b.eigenfunctions(xn)).max())
    assert _agrees(between_err, np.abs(num.eigenfunctions(x) * sign
                                       - exact_b.eigenfunctions(x)).max())
    coarse, fine = (KLBasis.build("squared_exponential", 0.3, interval(0.5), modes=6,
                                  method="nystrom", quadrature_points=q).eigenvalues
                    for q in (16, 400))
    assert "N = 16 agree with those with N = 400 to 1e-8 relative" in " ".join(section.split())
    assert _rel(coarse, fine).max() < 1e-8

    kept = re.search(r"\| b \| exponential: modes \(captured\) \|[^\n]*\n\|[^\n]*\n"
                     r"((?:\|[^\n]*\n)+)", section).group(1)
    for line in kept.splitlines():
        b, *cells = [c.strip() for c in line.split("|")[1:-1]]
        for kernel, cell in zip(("exponential", "squared_exponential"), cells):
            basis = KLBasis.build(kernel, float(b), np.array([0.0, 1.0]), captured_variance=0.95)
            modes, captured, *flag = re.match(r"(\d+) \(([0-9.]+)(, capped)?\)", cell).groups()
            assert int(modes) == basis.n_modes, (b, kernel)
            assert _agrees(captured, basis.captured_fraction), (b, kernel)
            assert (flag[0] is not None) == basis.capped, (b, kernel)


def test_modes_for_95_percent_follow_the_doc_estimate():
    """docs/fields.md: the exponential kernel needs roughly 12.7·|D|/(π b) modes for 95 %
    (from λ_j ≈ 2c/ω_j², ω_j ≈ jπ/|D|: the tail beyond M is 2|D|/(π² b M) of the total
    variance |D|, 5 % at M = 40|D|/(π² b) = 12.7·|D|/(π b))."""
    assert "12.7 · |D| / (π b)" in FIELDS_DOC.read_text(encoding="utf-8")
    for b in (0.02, 0.05, 0.1):
        modes = KLBasis.build("exponential", b, np.array([0.0, 1.0]),
                              captured_variance=0.95).n_modes
        assert abs(modes / (12.7 / (math.pi * b)) - 1) < 0.1, (b, modes)
