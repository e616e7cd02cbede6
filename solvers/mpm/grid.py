"""The background grid: geometry, padding and boundary-condition masks.

Nodes sit at ``(ox + i·dx, oy + j·dx)``, ``i = 0 … nnx-1``, ``j = 0 … nny-1``, with
``ox = x0 − pad·dx`` so the domain ``[x0, x0 + ncx·dx] × [y0, y0 + ncy·dx]`` is surrounded by
``pad`` (≥ 2) cells of padding: a particle anywhere inside the padded band still has its whole
3×3 stencil on the grid; a particle whose stencil would leave it is an error (guard).

The lower-left corner ``(x0, y0)`` is exact; the upper and right edges are the first grid
lines at or beyond ``x1`` and ``y1`` (a whole number of cells).

Sides (``left`` = x0, ``right`` = x1, ``bottom`` = y0, ``top`` = y1):

* ``free``: nothing is imposed (the padding nodes are ordinary nodes);
* ``fixed``: a rigid no-slip wall, by the image method: the padding (ghost) nodes' mass,
  momentum and force are folded onto their mirror nodes inside with both velocity components
  reversed (the odd image of the material), both components are zero on the boundary line,
  and the ghost nodes get the mirrored (reversed) velocity back before the gather;
* ``symmetry`` (alias ``roller``, a frictionless rigid wall): the same with only the normal
  component reversed (even tangential, odd normal image) and zero on the plane.

The image treatment makes the wall sit exactly on the boundary line with the B-spline
stencils that reach past it (zeroing every node on and beyond the line instead shifts the
effective wall by a fraction of a cell: the fixed–free bar's period is then off by ≈ 0.3 dx/L).

* ``absorbing`` (the far field): a viscous boundary (Lysmer & Kuhlemeyer 1969) — the nodes on
  the boundary line carry dashpots with the traction t = −ρ c_p v_n n − ρ c_s v_t t of the
  material next to the side (coefficients per node ρ c dx, per metre of thickness), so a
  plane wave at normal incidence leaves without reflection. The dashpot force is taken
  implicitly in the grid update, v = (p + f dt)/(m + η dt): stable for any η, and the node
  stops but never reverses when η dt ≫ m.

Clamps are rectangles whose nodes get zero velocity (both components).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

SIDES = ("left", "right", "bottom", "top")
SIDE_KINDS = {"free": 0, "fixed": 1, "roller": 2, "symmetry": 3, "absorbing": 4}
FREE, FIXED, ROLLER, SYMMETRY, ABSORBING = 0, 1, 2, 3, 4
MIRRORED = (FIXED, ROLLER, SYMMETRY)        # sides treated by the image method


@dataclass
class Grid:
    x0: float
    y0: float
    dx: float
    ncx: int
    ncy: int
    pad: int
    sides: dict = field(default_factory=lambda: dict.fromkeys(SIDES, "free"))
    clamps: list = field(default_factory=list)     # [(xmin, ymin, xmax, ymax), ...]
    # first cell of this grid on the scene's full grid (extent = "auto" crops): particle
    # lattice positions are computed from the full grid's corner, so a cropped run seeds
    # bit-identical positions
    ci0: int = 0
    cj0: int = 0

    @classmethod
    def cover(cls, x0, x1, y0, y1, dx, pad=3, sides=None, clamps=()):
        ncx = max(1, int(math.ceil((x1 - x0) / dx - 1e-9)))
        ncy = max(1, int(math.ceil((y1 - y0) / dx - 1e-9)))
        g = cls(float(x0), float(y0), float(dx), ncx, ncy, int(pad))
        if sides:
            g.sides.update(sides)
        g.clamps = [tuple(map(float, c)) for c in clamps]
        return g

    # -- geometry --------------------------------------------------------------------------
    @property
    def nnx(self):
        return self.ncx + 2 * self.pad + 1

    @property
    def nny(self):
        return self.ncy + 2 * self.pad + 1

    @property
    def ox(self):
        return self.x0 - self.pad * self.dx

    @property
    def oy(self):
        return self.y0 - self.pad * self.dx

    @property
    def x1(self):
        return self.x0 + self.ncx * self.dx

    @property
    def y1(self):
        return self.y0 + self.ncy * self.dx

    @property
    def cells(self):
        return self.ncx * self.ncy

    def node_x(self):
        return self.ox + self.dx * np.arange(self.nnx)

    def node_y(self):
        return self.oy + self.dx * np.arange(self.nny)

    # -- boundary conditions ---------------------------------------------------------------
    def side_codes(self):
        """int64[4]: kind of left, right, bottom, top (``SIDE_KINDS``)."""
        return np.array([SIDE_KINDS[self.sides[s]] for s in SIDES], dtype=np.int64)

    def boundary_nodes(self):
        """int64[4]: node index of the left, right, bottom, top boundary lines."""
        p = self.pad
        return np.array([p, p + self.ncx, p, p + self.ncy], dtype=np.int64)

    def folded_side_codes(self):
        """int64[4]: like ``side_codes`` but 0 for the sides without images (free, absorbing)."""
        return np.array([k if k in MIRRORED else FREE for k in self.side_codes()],
                        dtype=np.int64)

    def dashpots(self, impedance):
        """(eta_x, eta_y) float64[nnx, nny]: dashpot coefficients (kg s⁻¹ per metre of
        thickness) of the absorbing sides. ``impedance[side] = (ρ c_p, ρ c_s)``; the normal
        component takes ρ c_p dx, the tangential one ρ c_s dx; a corner node gets both sides'."""
        ex = np.zeros((self.nnx, self.nny))
        ey = np.zeros_like(ex)
        il, ir, jb, jt = self.boundary_nodes()
        lines = {"left": (il, slice(None)), "right": (ir, slice(None)),
                 "bottom": (slice(None), jb), "top": (slice(None), jt)}
        for side, line in lines.items():
            if self.sides[side] != "absorbing":
                continue
            zp, zs = impedance[side]
            normal, tangential = (ex, ey) if side in ("left", "right") else (ey, ex)
            normal[line] += zp * self.dx
            tangential[line] += zs * self.dx
        return ex, ey

    def masks(self):
        """(fixx, fixy) uint8[nnx, nny]: 1 where that velocity component is set to zero."""
        fx = np.zeros((self.nnx, self.nny), dtype=np.uint8)
        fy = np.zeros_like(fx)
        il, ir, jb, jt = self.boundary_nodes()
        # only the boundary lines: the ghost nodes beyond are overwritten by the image
        for side, line in (("left", (il, slice(None))), ("right", (ir, slice(None))),
                           ("bottom", (slice(None), jb)), ("top", (slice(None), jt))):
            kind = self.sides[side]
            if kind == "fixed":
                fx[line] = 1
                fy[line] = 1
            elif kind in ("roller", "symmetry"):
                (fx if side in ("left", "right") else fy)[line] = 1
        xs, ys = self.node_x(), self.node_y()
        tol = 1e-9 * self.dx
        for (a, b, c, d) in self.clamps:
            ii = (xs >= a - tol) & (xs <= c + tol)
            jj = (ys >= b - tol) & (ys <= d + tol)
            sel = np.ix_(ii, jj)
            fx[sel] = 1
            fy[sel] = 1
        return fx, fy
