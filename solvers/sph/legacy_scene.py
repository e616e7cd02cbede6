"""The SPH scene parsed by hand, kept only until the typed models (solvers/sph/scene.py) are
shown to give the same Config on every shipped scene (tests/solvers/sph/test_scene.py).


Every failure is a one-line SceneError naming ``scene.<key>``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from solvers.sph.kernel import KERNELS
from solvers.sph.problem import INTEGRATIONS, METHODS
from solvers.sph.stiffness import STATES
from uqflow.scene_checks import (check_keys, integer, number, number_pair, scene_error,
                                 table)

LAYOUTS = ("regular", "polar", "random")
LOADINGS = ("tension", "eigenstrain")
EIGENSTRAIN_MODES = ("in_plane", "dilatation_3d")
EDGES = ("exact", "fixed")
LINEAR_SOLVERS = ("auto", "direct", "iterative")
#: particles of one layout: the stiffness keeps ~160 nonzeros per particle pair of DOFs
#: (about 13 M entries, ~0.3 GB with indices, at 40,000 particles — the largest size measured
#: in benchmarks/sph_scaling.py); 10^5 keeps a run within a few GB
MAX_PARTICLES = 100_000
MAX_STEPS = 10_000
MAX_INCLUSIONS = 1_000
#: lambda + 2 mu of a phase (Pa): real solids are below 1e13; the headroom keeps the stiffness
#: sums (times 1/h² and volumes h², ~100 terms a row) and the penalty weights (below
#: MAX_PENALTY) far from overflow
MAX_STIFFNESS = 1e200
#: relative penalty weight: beyond 1/eps the stiffness itself is lost in the rounding
MAX_PENALTY = 1e16
#: below this smoothing ratio a square-lattice support holds fewer than 9 particles and the
#: linear correction is poorly conditioned at edges and corners (h = 2a holds 21)
MIN_SMOOTHING_RATIO = 1.0

KEYS = frozenset({
    "layout", "width", "height", "outer_radius", "spacing", "resolution", "inclusions", "random",
    "gap", "smoothing_ratio", "kernel", "integration", "stabilisation", "state", "thickness",
    "matrix", "inclusion", "interface_strength", "constraints", "cutoff_threshold",
    "cutoff_radius", "penalty", "min_support", "linear_solver", "loading", "eigenstrain",
    "eigenstrain_mode", "edge", "step", "steps"})
MATERIAL_KEYS = frozenset({"E", "nu"})
INCLUSION_KEYS = frozenset({"centre", "semi_axes", "angle_deg"})
RANDOM_KEYS = frozenset({"count", "semi_axes_min", "semi_axes_max", "layout_seed", "min_gap"})


@dataclass(frozen=True)
class InclusionSpec:
    centre: tuple[float, float]
    semi_axes: tuple[float, float]
    angle_deg: float


@dataclass(frozen=True)
class RandomSpec:
    count: int
    semi_axes_min: tuple[float, float]
    semi_axes_max: tuple[float, float]
    layout_seed: int
    #: the gap random sequential addition keeps (m); None: one support diameter
    min_gap: float | None = None


@dataclass(frozen=True)
class Config:
    layout: str
    width: float
    height: float
    outer_radius: float
    spacing: float                 # after resolution
    inclusions: tuple[InclusionSpec, ...]
    random: RandomSpec | None
    gap: float
    smoothing_ratio: float
    kernel: str
    integration: str
    stabilisation: float
    state: str
    thickness: float
    matrix: tuple[float, float]    # E, nu
    inclusion: tuple[float, float]
    interface_strength: float
    constraints: str
    cutoff_threshold: float
    cutoff_radius: float | None    # in support radii (2h)
    penalty: float
    min_support: int
    linear_solver: str
    loading: str
    eigenstrain: float
    eigenstrain_mode: str
    edge: str
    step: float
    steps: int


def _choice(v, key, options):
    if not isinstance(v, str) or v not in options:
        raise scene_error(key, f"must be one of {', '.join(options)}, got {v!r}")
    return v


def _material(v, key):
    tbl = table(v, key)
    check_keys(tbl, MATERIAL_KEYS, key)
    for k in ("E", "nu"):
        if k not in tbl:
            raise scene_error(f"{key}.{k}", "is required")
    E = number(tbl["E"], f"{key}.E", positive=True)
    nu = number(tbl["nu"], f"{key}.nu")
    if not 0.0 < nu < 0.5:
        raise scene_error(f"{key}.nu", f"must be in (0, 0.5), got {nu!r}")
    if not stiffness_scale(E, nu) <= MAX_STIFFNESS:
        raise scene_error(f"{key}.E", f"E = {E!r} with nu = {nu!r} gives lambda + 2 mu above "
                                      f"{MAX_STIFFNESS:g} Pa: the stiffness would overflow")
    return E, nu


def stiffness_scale(E: float, nu: float) -> float:
    """lambda + 2 mu of plane strain, the largest entry of the elastic matrix (inf when it
    overflows; plane stress's is smaller)."""
    with np.errstate(over="ignore"):
        return float(np.float64(E) * (1.0 - nu) / ((1.0 + nu) * (1.0 - 2.0 * nu)))


def _inclusions(v):
    if not isinstance(v, (list, tuple)):
        raise scene_error("inclusions", f"must be a list of tables, got {v!r}")
    if len(v) > MAX_INCLUSIONS:
        raise scene_error("inclusions", f"{len(v)} inclusions; at most {MAX_INCLUSIONS}")
    out = []
    for k, item in enumerate(v):
        key = f"inclusions[{k}]"
        tbl = table(item, key)
        check_keys(tbl, INCLUSION_KEYS, key)
        for req in ("centre", "semi_axes"):
            if req not in tbl:
                raise scene_error(f"{key}.{req}", "is required")
        a, b = number_pair(tbl["semi_axes"], f"{key}.semi_axes")
        if not (a > 0 and b > 0):
            raise scene_error(f"{key}.semi_axes", f"must be > 0, got {[a, b]!r}")
        angle = number(tbl.get("angle_deg", 0.0), f"{key}.angle_deg")
        out.append(InclusionSpec(number_pair(tbl["centre"], f"{key}.centre"), (a, b), angle))
    return tuple(out)


def _random(v):
    tbl = table(v, "random")
    check_keys(tbl, RANDOM_KEYS, "random")
    for req in ("count", "semi_axes_min", "semi_axes_max"):
        if req not in tbl:
            raise scene_error(f"random.{req}", "is required")
    lo = number_pair(tbl["semi_axes_min"], "random.semi_axes_min")
    hi = number_pair(tbl["semi_axes_max"], "random.semi_axes_max")
    if not all(x > 0 for x in lo):
        raise scene_error("random.semi_axes_min", f"must be > 0, got {list(lo)!r}")
    if not all(h >= x for h, x in zip(hi, lo)):
        raise scene_error("random.semi_axes_max", f"must be >= semi_axes_min {list(lo)!r}, "
                                                  f"got {list(hi)!r}")
    gap = number(tbl["min_gap"], "random.min_gap", positive=True) if "min_gap" in tbl else None
    return RandomSpec(integer(tbl["count"], "random.count", 1, MAX_INCLUSIONS), lo, hi,
                      integer(tbl.get("layout_seed", 0), "random.layout_seed", 0, 2**63 - 1),
                      gap)


def _particle_estimate(layout, width, height, outer, spacing) -> float:
    """Particles of the lattice (or rings), per axis so that neither an underflowing
    spacing² nor a plate thinner than one spacing hides the count (inf when it overflows)."""
    with np.errstate(over="ignore"):
        if layout == "polar":
            return float(np.pi * np.float64(outer / spacing) ** 2 + 1.0)
        return float((np.float64(width / spacing) + 1.0) * (np.float64(height / spacing) + 1.0))


def _check_fits(inc: InclusionSpec, k: int, layout, width, height, outer):
    """The ellipse inside the plate (or inside the polar disc): its interface particles are
    counted from its perimeter, which an ellipse beyond the domain would make unbounded."""
    a, b = inc.semi_axes
    key = f"inclusions[{k}]"
    if layout == "polar":
        if not a < outer:
            raise scene_error(f"{key}.semi_axes", f"radius {a:.4g} m is not inside the disc "
                                                  f"of outer_radius {outer:.4g} m")
        return
    t = math.radians(inc.angle_deg)
    # half extents of the rotated ellipse (hypot: no overflow of a² at 1e308)
    ex = math.hypot(a * math.cos(t), b * math.sin(t))
    ey = math.hypot(a * math.sin(t), b * math.cos(t))
    if not (2.0 * ex < width and 2.0 * ey < height):
        raise scene_error(f"{key}.semi_axes", f"an ellipse {2 * ex:.4g} x {2 * ey:.4g} m across "
                                              f"does not fit the {width:.4g} x {height:.4g} m "
                                              f"plate")
    cx, cy = inc.centre
    if not (abs(cx) + ex < 0.5 * width and abs(cy) + ey < 0.5 * height):
        raise scene_error(f"{key}.centre", f"the ellipse at {[cx, cy]!r} reaches beyond the "
                                           f"plate (the plate is centred at [0, 0])")


def parse(scene: Mapping) -> Config:
    """Validate ``scene`` and return its Config (geometry checks beyond single keys — overlap,
    distance to the boundary, supports — happen when the layout is built)."""
    if not isinstance(scene, Mapping):
        raise scene_error("", "must be a table")
    check_keys(scene, KEYS, "")
    s = scene
    layout = _choice(s.get("layout", "regular"), "layout", LAYOUTS)
    if "spacing" not in s:
        raise scene_error("spacing", "is required (the particle spacing, m)")
    resolution = number(s.get("resolution", 1.0), "resolution", positive=True)
    spacing = number(s["spacing"], "spacing", positive=True) / resolution
    width = height = outer = math.nan
    if layout == "polar":
        if "outer_radius" not in s:
            raise scene_error("outer_radius", "is required by layout = \"polar\"")
        outer = number(s["outer_radius"], "outer_radius", positive=True)
        area = math.pi * outer * outer
    else:
        for k in ("width", "height"):
            if k not in s:
                raise scene_error(k, f"is required by layout = {layout!r}")
        width = number(s["width"], "width", positive=True)
        height = number(s["height"], "height", positive=True)
        area = width * height
    count = _particle_estimate(layout, width, height, outer, spacing)
    if not count <= MAX_PARTICLES:
        raise scene_error("spacing" if resolution == 1.0 else "resolution",
                          f"about {count:,.0f} particles; at most {MAX_PARTICLES:,}"
                          if count < 1e15 else f"about {count:.3g} particles; at most "
                                               f"{MAX_PARTICLES:,}")
    inclusions = _inclusions(s.get("inclusions", []))
    for k, inc in enumerate(inclusions):
        _check_fits(inc, k, layout, width, height, outer)
    rnd = None
    if layout == "random":
        if "random" not in s:
            raise scene_error("random", "is required by layout = \"random\"")
        if inclusions:
            raise scene_error("inclusions", "is not used by layout = \"random\" (its inclusions "
                                            "come from [random])")
        rnd = _random(s["random"])
        widest = max(rnd.semi_axes_max)
        if not 2.0 * widest < min(width, height):
            raise scene_error("random.semi_axes_max", f"an ellipse {2 * widest:.4g} m across "
                                                      f"does not fit the {width:.4g} x "
                                                      f"{height:.4g} m plate")
        if rnd.min_gap is not None and not 2.0 * (max(rnd.semi_axes_min) + rnd.min_gap) < \
                min(width, height):
            raise scene_error("random.min_gap", f"{rnd.min_gap:.4g} m around even the smallest "
                                                f"ellipse does not fit the {width:.4g} x "
                                                f"{height:.4g} m plate")
    elif "random" in s:
        raise scene_error("random", f"applies only to layout = \"random\", not {layout!r}")
    if layout == "polar" and (len(inclusions) != 1 or inclusions[0].centre != (0.0, 0.0)
                              or inclusions[0].semi_axes[0] != inclusions[0].semi_axes[1]):
        raise scene_error("inclusions", "layout = \"polar\" takes one circular inclusion centred "
                                        "at [0, 0]")
    loading = _choice(s.get("loading", "tension"), "loading", LOADINGS)
    state = _choice(s.get("state", "plane_strain"), "state", STATES)
    mode = _choice(s.get("eigenstrain_mode", "in_plane"), "eigenstrain_mode", EIGENSTRAIN_MODES)
    if mode == "dilatation_3d" and state == "plane_stress":
        raise scene_error("eigenstrain_mode", "dilatation_3d needs state = \"plane_strain\" "
                                              "(plane stress leaves eps_zz free)")
    edge = _choice(s.get("edge", "exact"), "edge", EDGES)
    if loading == "eigenstrain" and edge == "exact":
        circle = (len(inclusions) == 1
                  and inclusions[0].semi_axes[0] == inclusions[0].semi_axes[1])
        if not circle:
            raise scene_error("edge", "\"exact\" needs one circular inclusion (the Eshelby "
                                      "solution); use edge = \"fixed\"")
    method = _choice(s.get("constraints", "master-slave"), "constraints", METHODS)
    cutoff_radius = s.get("cutoff_radius")
    if cutoff_radius is not None:
        cutoff_radius = number(cutoff_radius, "cutoff_radius", positive=True)
    for key, applies in (("cutoff_threshold", "master-slave-cutoff"),
                         ("cutoff_radius", "master-slave-cutoff"),
                         ("penalty", "penalty")):
        if key in s and method != applies:
            raise scene_error(key, f"applies only to constraints = \"{applies}\"")
    strength = s.get("interface_strength", math.inf)
    if not (isinstance(strength, float) and strength == math.inf):
        strength = number(strength, "interface_strength", positive=True)
    steps = integer(s.get("steps", 1), "steps", 1, MAX_STEPS)
    if loading == "tension" and "step" not in s:
        raise scene_error("step", "is required by loading = \"tension\" (m per load step)")
    step = number(s.get("step", 0.0), "step", nonnegative=True)
    if loading == "tension" and layout != "polar" and not 2.0 * step * steps <= height:
        raise scene_error("step", f"{steps} steps of {step:.4g} m stretch the {height:.4g} m "
                                  f"plate by more than 100 %: outside small strain")
    return Config(
        layout=layout, width=width, height=height, outer_radius=outer, spacing=spacing,
        inclusions=inclusions, random=rnd,
        gap=number(s.get("gap", 0.5), "gap", lo=0.1, hi=0.9),
        smoothing_ratio=number(s.get("smoothing_ratio", 2.0), "smoothing_ratio",
                               lo=MIN_SMOOTHING_RATIO, hi=6.0),
        kernel=_choice(s.get("kernel", "cubic_spline"), "kernel", KERNELS),
        integration=_choice(s.get("integration", "vci"), "integration", INTEGRATIONS),
        stabilisation=number(s.get("stabilisation", 0.0), "stabilisation", nonnegative=True),
        state=state, thickness=number(s.get("thickness", 1.0), "thickness", positive=True),
        matrix=_material(s.get("matrix", {}), "matrix"),
        inclusion=_material(s.get("inclusion", {}), "inclusion"),
        interface_strength=float(strength), constraints=method,
        cutoff_threshold=number(s.get("cutoff_threshold", 1e-12), "cutoff_threshold",
                                nonnegative=True, hi=1.0),
        cutoff_radius=cutoff_radius,
        penalty=number(s.get("penalty", 1e4), "penalty", positive=True, hi=MAX_PENALTY),
        min_support=integer(s.get("min_support", 5), "min_support", 3, 100),
        linear_solver=_choice(s.get("linear_solver", "auto"), "linear_solver", LINEAR_SOLVERS),
        loading=loading,
        eigenstrain=number(s.get("eigenstrain", 0.01), "eigenstrain", lo=-0.5, hi=0.5),
        eigenstrain_mode=mode, edge=edge,
        step=step, steps=steps)
