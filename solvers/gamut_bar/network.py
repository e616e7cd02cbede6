"""Grid, bonds, weights and the element list of the deformation-gamut network.

A bar of n local bonds (segments) and n + 1 points. Local bond i joins points i and i + 1;
a nonlocal bond (p, q) of degree m = q − p ≥ 2 exists while its length is within the cut-off.
Every bond, and every part of a local bond, becomes one elastic–perfectly-plastic (Jenkins)
element: force k (e − e_p), |force| ≤ k·l·ε_c. See docs/gamut_bar.md §3–§5 for the equations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uqflow.errors import SolverError

CUT_SLACK = 1e-9          # relative slack on the cut-off (bond lengths carry rounding)
DROP_FRACTION = 1e-9      # deficit sub-elements below this fraction of E_i·A go to the own share


# ------------------------------------------------------------------------------------------
# Grid (seed sec. 4.3, eq. 36)
# ------------------------------------------------------------------------------------------

def uniform_grid(n: int, length: float) -> np.ndarray:
    """Points of the uniform grid: spacing L/n."""
    return np.concatenate([[0.0], np.cumsum(np.full(n, length / n))])


def stochastic_grid(n: int, length: float, factor: float, min_fraction: float,
                    rng: np.random.Generator) -> np.ndarray:
    """Points of a stochastic grid (eq. 36): s_i = s̄ + f·sign(N(0,1))·U(0,1)·s̄.

    The spacings are rescaled so that they add up to L; spacings then below
    ``min_fraction``·s̄ (near-overlaps) are redrawn — for independent spacings this is the
    seed's redrawing of the whole grid, conditioned spacing by spacing.
    """
    sbar = length / n

    def draw(k):
        return sbar * (1.0 + factor * np.sign(rng.standard_normal(k)) * rng.random(k))

    s = draw(n)
    for _ in range(10_000):
        bad = s * (length / s.sum()) < min_fraction * sbar      # judged after rescaling to L
        if not bad.any():
            break
        s[bad] = draw(int(bad.sum()))
    else:
        raise SolverError(f"stochastic grid: could not draw spacings >= {min_fraction:g} of the "
                          f"mean (grid_factor {factor:g})")
    s *= length / s.sum()
    return np.concatenate([[0.0], np.cumsum(s)])


# ------------------------------------------------------------------------------------------
# Bonds and weights (eq. 13, 21-22, 32)
# ------------------------------------------------------------------------------------------

@dataclass
class Bonds:
    """Nonlocal bonds (p, q), q − p = degree ≥ 2, with length ≤ cut-off."""

    p: np.ndarray
    q: np.ndarray
    degree: np.ndarray
    length: np.ndarray

    @property
    def midpoint_index(self):
        """Twice the midpoint in index units (p + q): identifies midpoints on a uniform grid."""
        return self.p + self.q


def nonlocal_bonds(x: np.ndarray, cut_length: float) -> Bonds:
    """Every (p, q) with q − p ≥ 2 and x_q − x_p ≤ cut-off (n·k bonds, not n²)."""
    n = x.size - 1
    lim = cut_length * (1.0 + CUT_SLACK)
    ps, qs = [], []
    for d in range(2, n + 1):      # lengths grow with the degree: stop at the first empty one
        p = np.arange(0, n + 1 - d)
        keep = x[p + d] - x[p] <= lim
        if not keep.any():
            break
        ps.append(p[keep])
        qs.append(p[keep] + d)
    if not ps:
        e = np.zeros(0, dtype=np.int64)
        return Bonds(e, e, e, np.zeros(0))
    p = np.concatenate(ps).astype(np.int64)
    q = np.concatenate(qs).astype(np.int64)
    return Bonds(p, q, q - p, x[q] - x[p])


def _cells(x, sbar):
    """Edges of every point's cell (half-way to its neighbours; half a mean spacing beyond
    the ends): the volume dV of eq. 21 that a point stands for."""
    mid = 0.5 * (x[:-1] + x[1:])
    return (np.concatenate([[x[0] - 0.5 * sbar], mid]),
            np.concatenate([mid, [x[-1] + 0.5 * sbar]]))


def _clipped(lo, hi, a, b):
    """Length of [lo, hi] ∩ [a, b]."""
    return np.maximum(np.minimum(hi, b) - np.maximum(lo, a), 0.0)


def _virtual_sums(x, sigma, sbar, n_families):
    """Gaussian weight of the bonds a point would have to points beyond the bar's ends
    (continuing the mean spacing): per point, (left, right). Zero in the interior."""
    n = x.size - 1
    a, b = 1.5 * sbar, (n_families + 1.5) * sbar
    k = np.arange(1, n_families + 3)[None, :]
    pts = np.arange(n + 1)[:, None]
    out = []
    for dist, deg in (((x[:, None] - x[0]) + k * sbar, pts + k),           # left of x_0
                      ((x[n] - x[:, None]) + k * sbar, (n - pts) + k)):    # right of x_n
        c = np.where(deg >= 2, _clipped(dist - 0.5 * sbar, dist + 0.5 * sbar, a, b), 0.0)
        out.append((np.exp(-dist * dist / (2.0 * sigma * sigma)) * c).sum(axis=1) / sbar)
    return out[0], out[1]


def bond_weights(x, bonds: Bonds, sigma, sbar, n_families, multiplier=None):
    """Calibrated weight of every nonlocal bond (eq. 13, 21, 22, 32).

    Eq. 21 normalises y(l)·dV over the nonlocal volume of a point. Each point weights its
    right-going and, separately, its left-going nonlocal bonds by y(l) = exp(−l²/2σ²) (eq. 22)
    times the far point's cell length dV (in mean spacings, clipped to the nominal nonlocal
    range [1.5, M + 0.5] spacings) times the realization's multiplier μ (field ``bar.w``),
    normalised one-sided (eq. 13 and the factor 2 of eq. 32: each side sums to 1 for every
    realization). On a uniform grid dV = 1 and this is the plain normalised Gaussian. Near an
    end the normalisation also counts the bonds to points beyond the end (at the mean
    spacing); their weight is carried by the local bonds (end correction). A bond's weight is
    the mean of the weights its two end points give it.
    """
    n = x.size - 1
    lo_edge, hi_edge = _cells(x, sbar)
    a, b = 1.5 * sbar, (n_families + 1.5) * sbar
    y = np.exp(-bonds.length**2 / (2.0 * sigma * sigma))
    if multiplier is not None:
        y = y * multiplier
    cq = _clipped(lo_edge[bonds.q] - x[bonds.p], hi_edge[bonds.q] - x[bonds.p], a, b) / sbar
    cp = _clipped(x[bonds.q] - hi_edge[bonds.p], x[bonds.q] - lo_edge[bonds.p], a, b) / sbar
    vleft, vright = _virtual_sums(x, sigma, sbar, n_families)
    right = np.bincount(bonds.p, weights=y * cq, minlength=n + 1) + vright   # p's right-going
    left = np.bincount(bonds.q, weights=y * cp, minlength=n + 1) + vleft     # q's left-going
    return 0.5 * (y * cq / right[bonds.p] + y * cp / left[bonds.q])


def effective_sigma(n_points, bonds: Bonds, w, nominal):
    """σ_stdev of every point from its bonds' weights (eq. 31), nearest and farthest bond:
    σ = sqrt((l_far² − l_near²) / (2 ln(w_near / w_far))); ``nominal`` where a point has fewer
    than two nonlocal bonds or the weights do not decrease with length."""
    out = np.full(n_points, float(nominal))
    if bonds.p.size == 0:
        return out
    pts = np.concatenate([bonds.p, bonds.q])
    ln = np.concatenate([bonds.length, bonds.length])
    ww = np.concatenate([w, w])
    keep = ww > 0
    pts, ln, ww = pts[keep], ln[keep], ww[keep]
    order = np.lexsort((ln, pts))
    pts, ln, ww = pts[order], ln[order], ww[order]
    first = np.flatnonzero(np.r_[True, pts[1:] != pts[:-1]])
    last = np.r_[first[1:] - 1, pts.size - 1]
    ok = last > first
    first, last, who = first[ok], last[ok], pts[first[ok]]
    num = ln[last] ** 2 - ln[first] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        den = 2.0 * np.log(ww[first] / ww[last])
        val = np.sqrt(num / den)
    good = (num > 0) & (den > 0) & np.isfinite(val)
    out[who[good]] = val[good]
    return out


# ------------------------------------------------------------------------------------------
# Elements: nonlocal bonds, local bonds and the end/grid correction (patch test)
# ------------------------------------------------------------------------------------------

@dataclass
class Correction:
    """The grid and end correction of a grid (computed for the homogeneous nominal material).

    ``scale``: factor of every nonlocal bond (< 1 only where the nonlocal bonds would carry more
    than R·E·A across a cut); ``own``: the local bond's own share as a fraction of its nominal
    (1 − R − h)·E·A; ``topup[j, i]``: the local sub-element of family j at cut i as a fraction
    of the cut's nonlocal share R·E·A.
    """

    scale: np.ndarray
    own: np.ndarray
    topup: np.ndarray
    family: np.ndarray      # lower family index of every bond (0 = family 2)
    frac: np.ndarray        # position between that family and the next
    eps_c: np.ndarray       # critical strain of every bond


def _span_min(values, p, q):
    """min(values[p:q]) for every (p, q) (sparse table, q > p)."""
    table = [values]
    width = 1
    while 2 * width <= int((q - p).max()):
        prev = table[-1]
        table.append(np.minimum(prev[:-width], prev[width:]))
        width *= 2
    length = q - p
    level = np.floor(np.log2(length)).astype(np.int64)
    out = np.empty(p.size)
    for k in np.unique(level):
        sel = level == k
        t = table[k]
        out[sel] = np.minimum(t[p[sel]], t[q[sel] - (1 << k)])
    return out


def _family_fill(n, nf, bonds, kl, lo, frac):
    """Σ k·l per family and cut (difference arrays over the spanned cuts); a bond between two
    families counts in both, by its distance to each."""
    diff = np.zeros((nf + 1, n + 1))
    for f, part in ((lo, kl * (1.0 - frac)), (lo + 1, kl * frac)):
        np.add.at(diff, (f, bonds.p), part)
        np.add.at(diff, (f, bonds.q), -part)
    return np.cumsum(diff, axis=1)[:nf, :n]


def grid_correction(x, bonds: Bonds, w, sbar, cal, R, strains) -> Correction:
    """Grid and end correction so that every cut of the homogeneous bar carries E·A under
    uniform strain (the patch test, on any grid) with a share slipped by every strain as close
    as possible to the nominal one (docs/gamut_bar.md §5).

    1. Family of a bond: its length in mean spacings φ = l/s̄ within [2, M] (= its degree on a
       uniform grid); its critical strain is interpolated between the families' values.
    2. Where the nonlocal bonds crossing a cut carry more than R·E·A, every bond crossing it is
       scaled down (by the smallest ratio over the cuts it spans).
    3. Top-ups: per cut, local sub-elements of each family (and the own share) carry what the
       nonlocal bonds do not. If no family is over-filled this is exactly the missing share (ends
       of a uniform grid). Otherwise the top-ups are the non-negative least-squares fit of the
       cut's staircase σ(ε) to the nominal one at ``strains`` (relative error), with the total
       fixed — an over-filled family is paid for by its neighbours in slip order.
    """
    n = x.size - 1
    nf = cal.weights.size
    M = nf + 1
    phi = np.clip(bonds.length / sbar, 2.0, float(M))
    near = np.rint(phi)
    phi = np.where(np.abs(phi - near) < 1e-9, near, phi)
    lo = np.minimum(np.floor(phi), nf).astype(np.int64) - 2
    frac = phi - (lo + 2)
    eps_c = np.where(frac == 0.0, cal.eps_family[lo],
                     np.interp(phi, np.arange(2, M + 1), cal.eps_family))
    kl = R * w / bonds.degree                       # in units of E·A
    N = _family_fill(n, nf, bonds, kl, lo, frac).sum(axis=0)
    ratio = np.where(N > R * (1.0 + 1e-12), R / np.maximum(N, 1e-300), 1.0)
    scale = np.ones(bonds.p.size)
    if bonds.p.size and (ratio < 1.0).any():
        scale = np.minimum(_span_min(ratio, bonds.p, bonds.q), 1.0)
    fill = _family_fill(n, nf, bonds, kl * scale, lo, frac)
    h = cal.hardening
    shares = np.concatenate([[max(1.0 - R - h, 0.0)], R * cal.weights])   # slip order
    have = np.vstack([np.zeros((1, n)), fill])
    top = np.maximum(shares[:, None] - have, 0.0)
    over = (have - shares[:, None] > 1e-12).any(axis=0)
    if over.any():
        from scipy.optimize import nnls
        ec = np.concatenate([[cal.eps_local], cal.eps_family])
        G = np.minimum(strains[:, None], ec[None, :])
        target = G @ shares + h * strains
        G = G / target[:, None]
        budget = shares.sum() - have.sum(axis=0)
        big = 1e3
        A = np.vstack([G, np.full((1, shares.size), big)])
        for i in np.flatnonzero(over):
            b = np.concatenate([G @ (shares - have[:, i]), [big * budget[i]]])
            d, _ = nnls(A, b, maxiter=50 * shares.size)
            total = d.sum()
            top[:, i] = d * (budget[i] / total) if total > 0 else 0.0
    top[top < DROP_FRACTION] = 0.0
    own = np.where(shares[0] > 0, (top[0] + (shares.sum() - have.sum(axis=0) - top.sum(axis=0)))
                   / max(shares[0], 1e-300), 0.0)
    return Correction(scale=scale, own=np.maximum(own, 0.0),
                      topup=top[1:] / R, family=lo, frac=frac, eps_c=eps_c)


@dataclass
class Network:
    """Flat element arrays for the kernels, plus what the outputs need."""

    x: np.ndarray           # points (n + 1)
    seg: np.ndarray         # local bond lengths (n)
    ei: np.ndarray          # element end points (ei < ej)
    ej: np.ndarray
    k: np.ndarray           # stiffness [N/m]
    fc: np.ndarray          # critical force k·l·ε_c [N] (inf: never slips)
    cut_stiffness: np.ndarray   # Σ k·l of the elements crossing each cut [N] (= E_i A: patch)
    bandwidth: int


def build_network(x, E_seg, R_seg, area, bonds: Bonds, w, cal, corr: Correction,
                  E_ref: float | None = None) -> Network:
    """Elements of one realization (docs/gamut_bar.md §5).

    Nonlocal bond b of degree m: k_b l_b = s_b R_b w_b E_b A / m (m bonds of degree m cross each
    interior cut, so the nonlocal bonds carry R·E·A on the uniform interior), E_b the series
    (harmonic) mean and R_b the mean over the segments it spans, s_b the grid correction.
    Local bond i is a parallel set: the own share (1 − R_i − h) E_i A (times the correction),
    slipping first; a hardening share h·E_i A that never slips; the correction's top-ups
    (fractions of R_i E_i A) with their families' critical strains.

    Critical strains are calibrated for the reference modulus ``E_ref`` (the material's E);
    an element of another modulus keeps the critical *stress* E_ref·ε_c, so a random E field
    changes the bar's stiffness but not its strength: the localized equivalent-isotropic
    material of seed sec. 3.1.3 has a random E and the material's σ_y, σ_f.
    """
    n = x.size - 1
    seg = np.diff(x)
    EA = E_seg * area
    if bonds.p.size:
        c_comp = np.concatenate([[0.0], np.cumsum(seg / E_seg)])
        c_R = np.concatenate([[0.0], np.cumsum(seg * R_seg)])
        E_b = bonds.length / (c_comp[bonds.q] - c_comp[bonds.p])
        R_b = (c_R[bonds.q] - c_R[bonds.p]) / bonds.length
        kl = corr.scale * R_b * w * E_b * area / bonds.degree
    else:
        kl = np.zeros(0)
    own = corr.own * np.maximum(1.0 - R_seg - cal.hardening, 0.0) * EA
    hard = cal.hardening * EA
    D = corr.topup * (R_seg * EA)[None, :]
    cuts = np.arange(n)
    fi, ci = np.nonzero(D)
    E_ref = float(np.mean(E_seg)) if E_ref is None else float(E_ref)
    stiffer = E_ref / E_seg                       # ε_c scale per segment: fixed critical stress
    E_bond = E_b if bonds.p.size else np.zeros(0)
    parts = [  # (ei, ej, k·l, ε_c, length)
        (cuts, cuts + 1, own, cal.eps_local * stiffer, seg),
        (cuts, cuts + 1, hard, np.full(n, np.inf), seg),
        (ci, ci + 1, D[fi, ci], cal.eps_family[fi] * stiffer[ci], seg[ci]),
        (bonds.p, bonds.q, kl, corr.eps_c * (E_ref / E_bond), bonds.length),
    ]
    ei = np.concatenate([p[0] for p in parts]).astype(np.int64)
    ej = np.concatenate([p[1] for p in parts]).astype(np.int64)
    KL = np.concatenate([p[2] for p in parts])
    ec = np.concatenate([p[3] for p in parts])
    ln = np.concatenate([p[4] for p in parts])
    keep = KL > 0
    ei, ej, KL, ec, ln = ei[keep], ej[keep], KL[keep], ec[keep], ln[keep]
    order = np.lexsort((ej, ei))          # by first point: assembly walks memory in order
    ei, ej, KL, ec, ln = ei[order], ej[order], KL[order], ec[order], ln[order]
    with np.errstate(invalid="ignore"):
        fc = np.where(np.isinf(ec), np.inf, KL * ec)
    diff = np.zeros(n + 1)
    np.add.at(diff, ei, KL)
    np.add.at(diff, ej, -KL)
    return Network(x=x, seg=seg, ei=ei, ej=ej, k=KL / ln, fc=fc,
                   cut_stiffness=np.cumsum(diff)[:n],
                   bandwidth=int((ej - ei).max()) if ei.size else 1)
