"""Particle layouts of a matrix with elliptical inclusions (docs/sph.md § 6, "Layouts").

- ``regular_layout``: a square lattice aligned with a rectangular plate; lattice points within
  ``gap`` spacings of an interface are dropped and each interface gets particles at equal arc
  length, each doubled into a matrix particle and an inclusion particle at the same
  coordinates (a *pair*, seed Fig. 1).
- ``polar_layout``: rings around one circular inclusion (seed Example 1), the interface ring
  doubled into pairs, the outermost ring the plate's edge.
- ``random_layout``: random sequential addition of ellipses, every two of them and every one
  and the edge at least ``min_gap`` apart, then ``regular_layout``.

Volumes: each phase's particles share its exact area — near-Voronoi cells of the phase region
(sub-cell sampling, no sample on a cell edge), rescaled to the exact area; on a plain lattice
an interior particle gets spacing², an edge particle half, a corner a quarter. Mirror-symmetric
geometry gives bitwise mirror-symmetric particles (points are built in one octant or quadrant
and mirrored by sign flips and swaps), so a symmetry error measures the solver, not the layout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.special import ellipe

#: sub-cells per spacing (per direction) of the volume sampling: an even count never puts a
#: sample on a lattice cell's edge, at (i + 1/2) spacing
VOLUME_SAMPLES = 6


class LayoutError(ValueError):
    """Bad geometry, naming the scene key."""

    def __init__(self, key: str, reason: str):
        super().__init__(reason)
        self.key = key


@dataclass(frozen=True)
class Box:
    x0: float
    y0: float
    x1: float
    y1: float

    @property
    def area(self) -> float:
        return (self.x1 - self.x0) * (self.y1 - self.y0)


@dataclass(frozen=True)
class Disk:
    cx: float
    cy: float
    radius: float


@dataclass(frozen=True)
class Ellipse:
    cx: float
    cy: float
    a: float
    b: float
    angle: float = 0.0          # of the a axis from x, radians

    @property
    def area(self) -> float:
        return math.pi * self.a * self.b

    @property
    def perimeter(self) -> float:
        big, small = max(self.a, self.b), min(self.a, self.b)
        return 4.0 * big * float(ellipe(1.0 - (small / big) ** 2))

    def _local(self, points):
        p = np.asarray(points, dtype=float).reshape(-1, 2) - (self.cx, self.cy)
        c, s = math.cos(self.angle), math.sin(self.angle)
        return p[:, 0] * c + p[:, 1] * s, -p[:, 0] * s + p[:, 1] * c

    def _global(self, u, v):
        if self.angle == 0.0:
            return np.c_[u + self.cx, v + self.cy]
        c, s = math.cos(self.angle), math.sin(self.angle)
        return np.c_[u * c - v * s + self.cx, u * s + v * c + self.cy]

    def level(self, points) -> np.ndarray:
        u, v = self._local(points)
        return (u / self.a) ** 2 + (v / self.b) ** 2

    def contains(self, points) -> np.ndarray:
        return self.level(points) < 1.0

    def normal(self, points) -> np.ndarray:
        """Outward unit normal at points on the ellipse."""
        u, v = self._local(points)
        gu, gv = u / self.a ** 2, v / self.b ** 2
        norm = np.hypot(gu, gv)
        gu, gv = gu / norm, gv / norm
        c, s = math.cos(self.angle), math.sin(self.angle)
        return np.c_[gu * c - gv * s, gu * s + gv * c]

    def boundary_points(self, n: int) -> np.ndarray:
        """``n`` points (a multiple of 4; of 8 for a circle) at equal arc length, built in the
        first quadrant (octant) of the local frame and mirrored exactly."""
        if self.a == self.b:
            p = n // 8
            t = 2.0 * np.pi * np.arange(p + 1) / n
            u, v = self.a * np.cos(t), self.a * np.sin(t)
            u[-1] = v[-1] = self.a * math.sqrt(0.5)      # exactly on the diagonal
            v[0] = 0.0
            u = np.concatenate([u, v[:-1][::-1]])
            v = np.concatenate([v, u[:p][::-1]])
        else:
            q = n // 4
            t = _equal_arc_parameters(self.a, self.b, q)
            u, v = self.a * np.cos(t), self.b * np.sin(t)
            u[-1], v[0] = 0.0, 0.0
        # quadrant (0 .. pi/2 inclusive) -> full ring by sign flips, axis points once
        u = np.concatenate([u, -u[::-1][1:], -u[1:], u[::-1][1:-1]])
        v = np.concatenate([v, v[::-1][1:], -v[1:], -v[::-1][1:-1]])
        return self._global(u, v)

    def samples(self, spacing: float) -> np.ndarray:
        n = 4 * max(2, int(math.ceil(self.perimeter / spacing / 4.0)))
        t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
        return self._global(self.a * np.cos(t), self.b * np.sin(t))

    def distance_lower_bound(self, other) -> float:
        """A lower bound of the gap to ``other`` (Ellipse, Box edge or Disk edge); 0 when they
        overlap or one holds the other."""
        step = min(self.a, self.b) / 50.0
        mine = self.samples(step)
        if isinstance(other, Ellipse):
            theirs = other.samples(step)
            if other.contains(mine).any() or self.contains(theirs).any():
                return 0.0
            d = cKDTree(theirs).query(mine)[0].min()
            return max(0.0, float(d) - step)   # every boundary point is within step/2 of a sample
        if isinstance(other, Box):
            inside = ((mine[:, 0] > other.x0) & (mine[:, 0] < other.x1)
                      & (mine[:, 1] > other.y0) & (mine[:, 1] < other.y1))
            if not inside.all():
                return 0.0
            d = np.minimum.reduce([mine[:, 0] - other.x0, other.x1 - mine[:, 0],
                                   mine[:, 1] - other.y0, other.y1 - mine[:, 1]])
            return max(0.0, float(d.min()) - step)
        if isinstance(other, Disk):
            r = np.hypot(mine[:, 0] - other.cx, mine[:, 1] - other.cy)
            return max(0.0, float(other.radius - r.max()) - step)
        raise TypeError(f"no distance to {type(other).__name__}")


def _equal_arc_parameters(a, b, q):
    """Parameters t_0 = 0 .. t_q = pi/2 of points at equal arc length on a quarter ellipse."""
    t = np.linspace(0.0, 0.5 * np.pi, 64 * q + 1)
    speed = np.hypot(a * np.sin(t), b * np.cos(t))
    arc = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t))])
    out = np.interp(np.linspace(0.0, arc[-1], q + 1), arc, t)
    out[0], out[-1] = 0.0, 0.5 * np.pi
    return out


@dataclass(frozen=True)
class Layout:
    x: np.ndarray
    volume: np.ndarray
    phase: np.ndarray
    spacing: float
    domain: Box | Disk
    inclusions: tuple
    boundary: np.ndarray
    boundary_normal: np.ndarray
    boundary_weight: np.ndarray
    pairs: np.ndarray
    pair_normal: np.ndarray
    pair_weight: np.ndarray
    pair_inclusion: np.ndarray
    phase_area: np.ndarray

    @property
    def n(self) -> int:
        return self.x.shape[0]

    @property
    def n_inclusions(self) -> int:
        return len(self.inclusions)

    @property
    def volume_fraction(self) -> float:
        return float(self.phase_area[1:].sum() / self.phase_area.sum())


def _interface_count(e: Ellipse, spacing: float) -> int:
    unit = 8 if e.a == e.b else 4
    return unit * max(1, int(round(e.perimeter / spacing / unit)))


def _lattice_axis(lo, hi, spacing, key):
    cells = (hi - lo) / spacing
    n = int(round(cells))
    if n < 2 or abs(cells - n) > 1e-9 * max(cells, 1.0):
        raise LayoutError(key, f"the plate's side {hi - lo:.6g} m is not an integer multiple "
                               f"(>= 2) of the spacing {spacing:.6g} m")
    # symmetric about the centre to the last bit: (i - n/2) * spacing is odd in i - n/2
    return 0.5 * (lo + hi) + spacing * (np.arange(n + 1) - 0.5 * n)


def _volumes(points, phase, regions, spacing, bbox):
    """Near-Voronoi areas per phase: samples on a sub-grid, each to its nearest particle of the
    phase whose region holds it; then rescaled to the exact area of each phase."""
    x0, y0, x1, y1 = bbox
    h = spacing / VOLUME_SAMPLES
    gx = np.arange(x0 + 0.5 * h, x1, h)
    gy = np.arange(y0 + 0.5 * h, y1, h)
    volume = np.zeros(points.shape[0])
    for k, (inside, area) in enumerate(regions):
        members = np.flatnonzero(phase == k)
        counts = np.zeros(members.size)
        tree = cKDTree(points[members])
        for row in np.array_split(gy, max(1, gy.size // 256)):  # bounded memory
            S = np.c_[np.tile(gx, row.size), np.repeat(row, gx.size)]
            S = S[inside(S)]
            if S.size:
                counts += np.bincount(tree.query(S)[1], minlength=members.size)
        counts = np.maximum(counts, 0.5)   # a particle no sample reached keeps a sliver
        volume[members] = counts * (area / counts.sum())
    return volume


def regular_layout(box: Box, spacing: float, inclusions=(), gap: float = 0.5) -> Layout:
    if not spacing > 0:
        raise LayoutError("spacing", f"must be > 0, got {spacing!r}")
    inclusions = tuple(inclusions)
    xs = _lattice_axis(box.x0, box.x1, spacing, "width")
    ys = _lattice_axis(box.y0, box.y1, spacing, "height")
    clearance = gap * spacing
    for k, e in enumerate(inclusions):
        if not (e.a > 0 and e.b > 0):
            raise LayoutError(f"inclusions[{k}]", "semi-axes must be > 0")
        # before the distances: they sample the outline at min(a, b) / 50, which a
        # semi-axis of 1e-300 m would make ~1e300 samples
        if _interface_count(e, spacing) < 8 or min(e.a, e.b) < spacing:
            raise LayoutError(f"inclusions[{k}]", f"semi-axes {e.a:.4g}, {e.b:.4g} m are below "
                                                  f"the spacing {spacing:.4g} m")
        if e.distance_lower_bound(box) <= clearance:
            raise LayoutError(f"inclusions[{k}]", "crosses or touches the plate's edge")
        for j in range(k):
            if e.distance_lower_bound(inclusions[j]) <= 2.0 * clearance:
                raise LayoutError(f"inclusions[{k}]", f"overlaps or touches inclusions[{j}]")
    I, J = np.meshgrid(np.arange(xs.size), np.arange(ys.size))
    I, J = I.ravel(), J.ravel()
    lattice = np.c_[xs[I], ys[J]]
    owner = np.zeros(lattice.shape[0], dtype=np.int32)
    keep = np.ones(lattice.shape[0], dtype=bool)
    rings = []
    for k, e in enumerate(inclusions):
        ring = e.boundary_points(_interface_count(e, spacing))
        rings.append(ring)
        dense = e.samples(spacing / 20.0)
        near = cKDTree(dense).query(lattice)[0] < clearance
        keep &= ~near
        owner[e.contains(lattice)] = k + 1
    edge = (I == 0) | (I == xs.size - 1) | (J == 0) | (J == ys.size - 1)
    lattice, owner, edge, I, J = lattice[keep], owner[keep], edge[keep], I[keep], J[keep]
    n_lat = lattice.shape[0]
    ring_pts = np.concatenate(rings) if rings else np.zeros((0, 2))
    ring_owner = np.concatenate([np.full(r.shape[0], k) for k, r in enumerate(rings)]) \
        if rings else np.zeros(0, int)
    npair = ring_pts.shape[0]
    x = np.concatenate([lattice, ring_pts, ring_pts])
    phase = np.concatenate([owner, np.zeros(npair, np.int32),
                            (ring_owner + 1).astype(np.int32)])
    pairs = np.c_[n_lat + np.arange(npair), n_lat + npair + np.arange(npair)]
    pair_normal = np.concatenate([e.normal(r) for e, r in zip(inclusions, rings)]) \
        if rings else np.zeros((0, 2))
    pair_weight = np.concatenate([np.full(r.shape[0], e.perimeter / r.shape[0])
                                  for e, r in zip(inclusions, rings)]) if rings else np.zeros(0)
    boundary = np.flatnonzero(edge)
    bi, bj = I[boundary], J[boundary]
    normal = np.c_[np.where(bi == 0, -1.0, np.where(bi == xs.size - 1, 1.0, 0.0)),
                   np.where(bj == 0, -1.0, np.where(bj == ys.size - 1, 1.0, 0.0))]
    normal /= np.hypot(normal[:, 0], normal[:, 1])[:, None]
    areas = [box.area - sum(e.area for e in inclusions)] + [e.area for e in inclusions]

    def matrix_region(S):
        out = np.ones(S.shape[0], dtype=bool)
        for e in inclusions:
            out &= ~e.contains(S)
        return out
    regions = [(matrix_region, areas[0])] + [(e.contains, e.area) for e in inclusions]
    volume = _volumes(x, phase, regions, spacing, (box.x0, box.y0, box.x1, box.y1))
    return Layout(x=x, volume=volume, phase=phase, spacing=spacing, domain=box,
                  inclusions=inclusions, boundary=boundary, boundary_normal=normal,
                  boundary_weight=np.full(boundary.size, spacing), pairs=pairs,
                  pair_normal=pair_normal, pair_weight=pair_weight,
                  pair_inclusion=ring_owner.astype(np.int64), phase_area=np.array(areas))


def _ring(r, n):
    return Ellipse(0.0, 0.0, r, r).boundary_points(n)


def polar_layout(radius: float, outer_radius: float, spacing: float) -> Layout:
    """Example 1: rings of particles around a circular inclusion of ``radius`` centred at the
    origin, in a disc of ``outer_radius`` whose edge ring carries the boundary condition."""
    if not (spacing > 0 and radius > 0):
        raise LayoutError("spacing", "spacing and radius must be > 0")
    if not outer_radius > radius + 2.0 * spacing:
        raise LayoutError("outer_radius", f"must exceed the inclusion radius {radius:.6g} by "
                                          f"two spacings at least")
    m = max(2, int(round(radius / spacing)))
    M = max(2, int(round((outer_radius - radius) / spacing)))
    r_in = radius * np.arange(1, m) / m
    r_out = radius + (outer_radius - radius) * np.arange(1, M + 1) / M
    r_out[-1] = outer_radius
    count = lambda r: 8 * max(1, int(round(2.0 * np.pi * r / spacing / 8.0)))  # noqa: E731
    inc = np.concatenate([[0.0], r_in, [radius]])
    mat = np.concatenate([[radius], r_out])
    mid = lambda r: 0.5 * (r[1:] + r[:-1])  # noqa: E731
    # each ring owns the annulus between the midradii around it; the two interface rings
    # split at the interface, so each phase's cells tile its exact area
    radii = np.concatenate([inc, mat])
    lower = np.concatenate([[0.0], mid(inc), [radius], mid(mat)])
    upper = np.concatenate([mid(inc), [radius], mid(mat), [outer_radius]])
    phases = np.concatenate([np.ones(inc.size, int), np.zeros(mat.size, int)])
    xs, ph, vol, ring_id = [np.zeros((1, 2))], [np.array([1])], [], []
    vol.append(np.array([np.pi * upper[0] ** 2]))
    ring_id.append(np.array([0]))
    for i in range(1, radii.size):
        n = count(radii[i])
        pts = _ring(radii[i], n)
        xs.append(pts)
        ph.append(np.full(n, phases[i]))
        vol.append(np.full(n, np.pi * (upper[i] ** 2 - lower[i] ** 2) / n))
        ring_id.append(np.full(n, i))
    x = np.concatenate(xs)
    phase = np.concatenate(ph).astype(np.int32)
    volume = np.concatenate(vol)
    ring_id = np.concatenate(ring_id)
    inc_ring = np.flatnonzero(ring_id == m)
    mat_ring = np.flatnonzero(ring_id == m + 1)
    boundary = np.flatnonzero(ring_id == radii.size - 1)
    n_if, n_b = inc_ring.size, boundary.size
    circle = Ellipse(0.0, 0.0, radius, radius)
    return Layout(x=x, volume=volume, phase=phase, spacing=spacing,
                  domain=Disk(0.0, 0.0, outer_radius), inclusions=(circle,),
                  boundary=boundary, boundary_normal=x[boundary] / outer_radius,
                  boundary_weight=np.full(n_b, 2.0 * np.pi * outer_radius / n_b),
                  pairs=np.c_[mat_ring, inc_ring], pair_normal=x[mat_ring] / radius,
                  pair_weight=np.full(n_if, 2.0 * np.pi * radius / n_if),
                  pair_inclusion=np.zeros(n_if, dtype=np.int64),
                  phase_area=np.array([np.pi * (outer_radius ** 2 - radius ** 2),
                                       np.pi * radius ** 2]))


def random_layout(box: Box, spacing: float, count: int, semi_axes_range, rng,
                  min_gap: float, max_attempts: int = 100_000) -> Layout:
    """Random sequential addition of ``count`` ellipses (centre and angle uniform, semi-axes
    uniform in ``semi_axes_range = ((a_min, b_min), (a_max, b_max))``), each at least
    ``min_gap`` from the others and from the edge; then ``regular_layout``."""
    (a_lo, b_lo), (a_hi, b_hi) = semi_axes_range
    if min(a_hi, b_hi) < spacing:
        # every ellipse drawn would fail regular_layout (narrower than the spacing): said at
        # once, not after sampling outlines thinner than the spacing
        raise LayoutError("random.semi_axes_max", f"{min(a_hi, b_hi):.4g} m is below the "
                                                  f"spacing {spacing:.4g} m: every ellipse "
                                                  f"drawn would be narrower than it")
    placed: list[Ellipse] = []
    attempts = 0
    while len(placed) < count:
        if attempts >= max_attempts:
            raise LayoutError("random.count", f"placed {len(placed)} of {count} inclusions in "
                                              f"{max_attempts} attempts (gap {min_gap:.4g} m)")
        attempts += 1
        a, b = rng.uniform(a_lo, a_hi), rng.uniform(b_lo, b_hi)
        angle = rng.uniform(0.0, np.pi)
        reach = max(a, b) + min_gap
        if box.x1 - box.x0 <= 2 * reach or box.y1 - box.y0 <= 2 * reach:
            continue
        e = Ellipse(rng.uniform(box.x0 + reach, box.x1 - reach),
                    rng.uniform(box.y0 + reach, box.y1 - reach), a, b, angle)
        # circles around and inside each ellipse settle most candidates without sampling
        near = [o for o in placed
                if math.hypot(e.cx - o.cx, e.cy - o.cy) <= max(e.a, e.b) + max(o.a, o.b) + min_gap]
        if any(math.hypot(e.cx - o.cx, e.cy - o.cy) < min(e.a, e.b) + min(o.a, o.b) + min_gap
               for o in near):
            continue
        if any(e.distance_lower_bound(o) < min_gap for o in near):
            continue
        placed.append(e)
    return regular_layout(box, spacing, placed)
