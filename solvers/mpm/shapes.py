"""Grid shape functions of the MPM solver (1-D factors of a tensor product).

Every kind is evaluated on the same 3-node stencil ``base, base + 1, base + 2`` with
``base = floor(xi - 0.5)`` (``xi`` the particle position in cell units from node 0), so the
scatter/gather kernels have one code path:

* ``QUADRATIC`` (default): the uniform quadratic B-spline, C¹, support 3 cells. No cell-crossing
  noise (its gradient is continuous).
* ``LINEAR``: the hat function; its gradient jumps when a particle crosses a cell face
  (the classic MPM cell-crossing instability) — kept for comparison.
* ``GIMP``: uniform GIMP (Bardenhagen & Kober 2004) with particle half-width ``lp`` (in cell
  units, ≤ 0.5), the hat convolved with the particle's box; lp is the undeformed half-width
  ``1 / (2 · particles_per_cell)``.

``shape1d`` returns the three weights and their derivatives with respect to ``xi`` (multiply by
``1/dx`` for physical gradients).
"""

from __future__ import annotations

import math

from numba import njit

QUADRATIC = 0
LINEAR = 1
GIMP = 2
KINDS = {"quadratic": QUADRATIC, "linear": LINEAR, "gimp": GIMP}


@njit(cache=True)
def _kernel(kind, r, lp):
    """Weight and d(weight)/d(xi) of a node at signed distance r = xi - node (cell units)."""
    a = abs(r)
    s = 1.0 if r >= 0.0 else -1.0
    if kind == QUADRATIC:
        if a < 0.5:
            return 0.75 - r * r, -2.0 * r
        if a < 1.5:
            t = 1.5 - a
            return 0.5 * t * t, -t * s
        return 0.0, 0.0
    if kind == LINEAR:
        if a < 1.0:
            return 1.0 - a, -s
        return 0.0, 0.0
    # uniform GIMP, half-width lp (0 < lp <= 0.5)
    if a < lp:
        return 1.0 - (r * r + lp * lp) / (2.0 * lp), -r / lp
    if a < 1.0 - lp:
        return 1.0 - a, -s
    if a < 1.0 + lp:
        t = 1.0 + lp - a
        return t * t / (4.0 * lp), -t / (2.0 * lp) * s
    return 0.0, 0.0


@njit(cache=True, forceinline=True)
def stencil_base(xi):
    """The first node of the 3-node stencil of position ``xi`` (cell units), every kind."""
    return int(math.floor(xi - 0.5))


@njit(cache=True, forceinline=True)
def shape1d(kind, xi, lp):
    """(base, w0, w1, w2, d0, d1, d2) of position ``xi`` (cell units from node 0)."""
    base = stencil_base(xi)
    r = xi - base
    if kind == QUADRATIC:
        # r in [0.5, 1.5): the three pieces are known, no branch per node (the hot path)
        a, b, c = 1.5 - r, r - 1.0, r - 0.5
        return base, 0.5 * a * a, 0.75 - b * b, 0.5 * c * c, -a, -2.0 * b, c
    w0, w1, w2, d0, d1, d2 = _weights_linear_or_gimp(kind, r, lp)
    return base, w0, w1, w2, d0, d1, d2


@njit(cache=True)
def _weights_linear_or_gimp(kind, r, lp):
    """The three weights and derivatives of the comparison kinds, called, not inlined:
    pasted into every stencil, their branches tripled the stencil's compile time, which
    every run pays for; the quadratic hot path never comes here (issue 19)."""
    w0, d0 = _kernel(kind, r, lp)
    w1, d1 = _kernel(kind, r - 1.0, lp)
    w2, d2 = _kernel(kind, r - 2.0, lp)
    return w0, w1, w2, d0, d1, d2
