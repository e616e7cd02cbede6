"""The SPH scene: keys, defaults, limits (docs/sph.md § 7, "Scene keys").

``SceneSpec`` declares what a scene file may say, key by key (pydantic, as uqflow.study declares
a study file); ``parse`` checks what joins several keys (a layout's required keys, an inclusion
that must fit the plate, the particle count) and resolves the scene into the ``Config`` the
solver builds from. Every failure is a one-line SceneError naming ``scene.<key>``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Annotated, Literal

import numpy as np
from pydantic import (AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field,
                      ValidationError, field_validator)

from solvers.sph.kernel import KERNELS
from solvers.sph.problem import INTEGRATIONS, METHODS
from solvers.sph.stiffness import STATES
from uqflow.errors import SceneError
from uqflow.scene_checks import is_number, scene_error
from uqflow.validation import validation_error

LAYOUTS = ("regular", "polar", "random")
LOADINGS = ("tension", "eigenstrain")
EIGENSTRAIN_MODES = ("in_plane", "dilatation_3d")
EDGES = ("exact", "fixed")
LINEAR_SOLVERS = ("auto", "direct", "iterative", "pardiso")
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
#: the largest layout_seed numpy's generators take from a TOML integer
MAX_LAYOUT_SEED = 2**63 - 1


# ------------------------------------------------------------------------------ value types
def _finite_number(value) -> float:
    # a TOML boolean is no number, nor an integer beyond float64 (uqflow.scene_checks)
    if not is_number(value):
        raise ValueError(f"must be a finite number, got {value!r}")
    try:
        value = float(value)
    except OverflowError:       # an integer between the largest float and 2^1024
        raise ValueError(f"must be a finite number, got {value!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"must be a finite number, got {value!r}")
    return value


def _whole_number(value) -> int:
    if not isinstance(value, (int, np.integer)) or isinstance(value, bool):
        raise ValueError(f"must be an integer, got {value!r}")
    return int(value)


def _number_pair(value) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ValueError(f"must be a pair of finite numbers [a, b], got {value!r}")
    try:
        return _finite_number(value[0]), _finite_number(value[1])
    except ValueError:
        raise ValueError(f"must be a pair of finite numbers [a, b], got {value!r}") from None


def _positive_pair(pair: tuple[float, float]) -> tuple[float, float]:
    if not (pair[0] > 0 and pair[1] > 0):
        raise ValueError(f"must be > 0, got {list(pair)!r}")
    return pair


def _strength(value) -> float:
    # an interface that never breaks is written inf (TOML's infinity), or left out
    if isinstance(value, float) and value == math.inf:
        return value
    return _finite_number(value)


Number = Annotated[float, BeforeValidator(_finite_number)]
Positive = Annotated[Number, Field(gt=0)]
NonNegative = Annotated[Number, Field(ge=0)]
Integer = Annotated[int, BeforeValidator(_whole_number)]
Pair = Annotated[tuple[float, float], BeforeValidator(_number_pair)]
PositivePair = Annotated[Pair, AfterValidator(_positive_pair)]


class _SceneTable(BaseModel):
    # every key is checked (an unknown one is refused, naming the keys it could be); values
    # are never coerced from strings or booleans
    model_config = ConfigDict(extra="forbid", frozen=True)


def stiffness_scale(E: float, nu: float) -> float:
    """lambda + 2 mu of plane strain, the largest entry of the elastic matrix (inf when it
    overflows; plane stress's is smaller)."""
    with np.errstate(over="ignore"):
        return float(np.float64(E) * (1.0 - nu) / ((1.0 + nu) * (1.0 - 2.0 * nu)))


# ------------------------------------------------------------------------------ declarations
class Material(_SceneTable):
    """An isotropic elastic phase. ``nu`` is declared first so that ``E``'s check sees it."""

    nu: Annotated[Number, Field(gt=0.0, lt=0.5)]
    E: Positive

    @field_validator("E")
    @classmethod
    def _stiffness_stays_finite(cls, E, info):
        nu = info.data.get("nu")
        if nu is not None and not stiffness_scale(E, nu) <= MAX_STIFFNESS:
            raise ValueError(f"E = {E!r} with nu = {nu!r} gives lambda + 2 mu above "
                             f"{MAX_STIFFNESS:g} Pa: the stiffness would overflow")
        return E


class InclusionSpec(_SceneTable):
    """An elliptic inclusion: centre (m, the plate centred at [0, 0]), semi-axes (m), and the
    angle of its first axis from x (degrees)."""

    centre: Pair
    semi_axes: PositivePair
    angle_deg: Number = 0.0


class RandomSpec(_SceneTable):
    """``count`` ellipses drawn by random sequential addition from ``layout_seed``."""

    count: Annotated[Integer, Field(ge=1, le=MAX_INCLUSIONS)]
    semi_axes_min: PositivePair
    semi_axes_max: Pair
    layout_seed: Annotated[Integer, Field(ge=0, le=MAX_LAYOUT_SEED)] = 0
    #: the gap random sequential addition keeps (m); None: one support diameter
    min_gap: Positive | None = None


class SceneSpec(_SceneTable):
    """The keys of an SPH scene table, their types, defaults and single-key limits."""

    layout: Literal[LAYOUTS] = "regular"
    width: Positive | None = None
    height: Positive | None = None
    outer_radius: Positive | None = None
    spacing: Positive
    resolution: Positive = 1.0
    inclusions: list[InclusionSpec] = Field(default_factory=list, max_length=MAX_INCLUSIONS)
    random: RandomSpec | None = None
    gap: Annotated[Number, Field(ge=0.1, le=0.9)] = 0.5
    smoothing_ratio: Annotated[Number, Field(ge=MIN_SMOOTHING_RATIO, le=6.0)] = 2.0
    kernel: Literal[KERNELS] = "cubic_spline"
    integration: Literal[INTEGRATIONS] = "vci"
    stabilisation: NonNegative = 0.0
    state: Literal[STATES] = "plane_strain"
    thickness: Positive = 1.0
    matrix: Material
    inclusion: Material
    interface_strength: Annotated[float, BeforeValidator(_strength), Field(gt=0)] = math.inf
    constraints: Literal[METHODS] = "master-slave"
    cutoff_threshold: Annotated[Number, Field(ge=0.0, le=1.0)] = 1e-12
    #: in support radii (2h)
    cutoff_radius: Positive | None = None
    penalty: Annotated[Number, Field(gt=0, le=MAX_PENALTY)] = 1e4
    min_support: Annotated[Integer, Field(ge=3, le=100)] = 5
    linear_solver: Literal[LINEAR_SOLVERS] = "auto"
    loading: Literal[LOADINGS] = "tension"
    eigenstrain: Annotated[Number, Field(ge=-0.5, le=0.5)] = 0.01
    eigenstrain_mode: Literal[EIGENSTRAIN_MODES] = "in_plane"
    edge: Literal[EDGES] = "exact"
    #: m per load step
    step: NonNegative = 0.0
    steps: Annotated[Integer, Field(ge=1, le=MAX_STEPS)] = 1


# ------------------------------------------------------------------------------ the resolved scene
@dataclass(frozen=True)
class Config:
    """The scene as the solver builds from it: the keys of ``SceneSpec`` with its defaults,
    the spacing after ``resolution``, and NaN for the sizes the layout does not use."""

    layout: str
    width: float                   # NaN for layout = "polar"
    height: float
    outer_radius: float            # NaN but for layout = "polar"
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


def parse(scene: Mapping) -> Config:
    """Validate ``scene`` and return its Config (geometry checks beyond these — overlap,
    distance to the boundary, supports — happen when the layout is built)."""
    s = _validated(scene)
    if s.layout == "polar":
        if s.outer_radius is None:
            raise scene_error("outer_radius", "is required by layout = \"polar\"")
        width = height = math.nan
        outer = s.outer_radius
    else:
        for key in ("width", "height"):
            if getattr(s, key) is None:
                raise scene_error(key, f"is required by layout = {s.layout!r}")
        width, height, outer = s.width, s.height, math.nan
    spacing = s.spacing / s.resolution
    _check_particle_count(s, width, height, outer, spacing)
    inclusions = tuple(s.inclusions)
    for k, inc in enumerate(inclusions):
        _check_fits(inc, k, s.layout, width, height, outer)
    _check_random(s, width, height)
    _check_loading(s)
    return Config(
        layout=s.layout, width=width, height=height, outer_radius=outer, spacing=spacing,
        inclusions=inclusions, random=s.random, gap=s.gap, smoothing_ratio=s.smoothing_ratio,
        kernel=s.kernel, integration=s.integration, stabilisation=s.stabilisation,
        state=s.state, thickness=s.thickness, matrix=(s.matrix.E, s.matrix.nu),
        inclusion=(s.inclusion.E, s.inclusion.nu), interface_strength=s.interface_strength,
        constraints=s.constraints, cutoff_threshold=s.cutoff_threshold,
        cutoff_radius=s.cutoff_radius, penalty=s.penalty, min_support=s.min_support,
        linear_solver=s.linear_solver, loading=s.loading, eigenstrain=s.eigenstrain,
        eigenstrain_mode=s.eigenstrain_mode, edge=s.edge, step=s.step, steps=s.steps)


def _validated(scene) -> SceneSpec:
    """``scene`` checked key by key; pydantic's first complaint as a one-line SceneError (the
    study loader's message and key, through uqflow.validation.validation_error)."""
    if not isinstance(scene, Mapping):
        raise SceneError(f"must be a table, got {scene!r}", key="scene")
    data = dict(scene)
    try:
        return SceneSpec.model_validate(data)
    except ValidationError as exc:
        found = validation_error(exc, None, prefix="scene", data=data, model=SceneSpec)
        raise SceneError(found.reason, key=found.key) from None


def _particle_estimate(layout, width, height, outer, spacing) -> float:
    """Particles of the lattice (or rings), per axis so that neither an underflowing
    spacing² nor a plate thinner than one spacing hides the count (inf when it overflows)."""
    with np.errstate(over="ignore"):
        if layout == "polar":
            return float(np.pi * np.float64(outer / spacing) ** 2 + 1.0)
        return float((np.float64(width / spacing) + 1.0) * (np.float64(height / spacing) + 1.0))


def _check_particle_count(s: SceneSpec, width, height, outer, spacing):
    count = _particle_estimate(s.layout, width, height, outer, spacing)
    if not count <= MAX_PARTICLES:
        raise scene_error("spacing" if s.resolution == 1.0 else "resolution",
                          f"about {count:,.0f} particles; at most {MAX_PARTICLES:,}"
                          if count < 1e15 else f"about {count:.3g} particles; at most "
                                               f"{MAX_PARTICLES:,}")


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


def _check_random(s: SceneSpec, width, height):
    """[random] belongs to layout = "random" (and replaces inclusions there); its ellipses and
    their gap fit the plate; a polar layout holds one centred circle."""
    if s.layout == "random":
        if s.random is None:
            raise scene_error("random", "is required by layout = \"random\"")
        if s.inclusions:
            raise scene_error("inclusions", "is not used by layout = \"random\" (its inclusions "
                                            "come from [random])")
        rnd = s.random
        if not all(h >= x for h, x in zip(rnd.semi_axes_max, rnd.semi_axes_min)):
            raise scene_error("random.semi_axes_max", f"must be >= semi_axes_min "
                                                      f"{list(rnd.semi_axes_min)!r}, got "
                                                      f"{list(rnd.semi_axes_max)!r}")
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
    elif s.random is not None:
        raise scene_error("random", f"applies only to layout = \"random\", not {s.layout!r}")
    inc = s.inclusions
    if s.layout == "polar" and (len(inc) != 1 or inc[0].centre != (0.0, 0.0)
                                or inc[0].semi_axes[0] != inc[0].semi_axes[1]):
        raise scene_error("inclusions", "layout = \"polar\" takes one circular inclusion centred "
                                        "at [0, 0]")


def _check_loading(s: SceneSpec):
    """Keys that apply to one loading, edge or constraint method only, and their consistency."""
    given = s.model_fields_set
    if s.eigenstrain_mode == "dilatation_3d" and s.state == "plane_stress":
        raise scene_error("eigenstrain_mode", "dilatation_3d needs state = \"plane_strain\" "
                                              "(plane stress leaves eps_zz free)")
    if s.loading == "eigenstrain" and s.edge == "exact":
        inc = s.inclusions
        if not (len(inc) == 1 and inc[0].semi_axes[0] == inc[0].semi_axes[1]):
            raise scene_error("edge", "\"exact\" needs one circular inclusion (the Eshelby "
                                      "solution); use edge = \"fixed\"")
    for key, applies in (("cutoff_threshold", "master-slave-cutoff"),
                         ("cutoff_radius", "master-slave-cutoff"),
                         ("penalty", "penalty")):
        if key in given and s.constraints != applies:
            raise scene_error(key, f"applies only to constraints = \"{applies}\"")
    if s.loading == "tension" and "step" not in given:
        raise scene_error("step", "is required by loading = \"tension\" (m per load step)")
    if s.loading == "tension" and s.layout != "polar" and not 2.0 * s.step * s.steps <= s.height:
        raise scene_error("step", f"{s.steps} steps of {s.step:.4g} m stretch the "
                                  f"{s.height:.4g} m plate by more than 100 %: outside small "
                                  f"strain")
