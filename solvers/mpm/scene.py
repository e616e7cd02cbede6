"""The MPM scene: its declaration (pydantic models, ``SceneSpec`` and one model per table;
errors are one-line ``SceneError`` naming ``scene.<key>``), the run's ``Config`` built from
it (``parse``), particle seeding and probe placement. Numerics live in ``step.py``; the run
in ``solver.py``. Every key, its type and default: docs/mpm_scenes.md.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import partial
from typing import Annotated

import numpy as np
from pydantic import (BaseModel, BeforeValidator, ConfigDict, ValidationError, field_validator,
                      model_validator)

from solvers.mpm.grid import SIDE_KINDS, Grid
from solvers.mpm.shapes import KINDS
from uqflow.errors import SceneError
from uqflow.scene_checks import is_number
from uqflow.validation import validation_error

# "seed": the conventions under which seed 000's tables are reproduced (docs/mpm.md,
# "Conventions"); the kernels read the rate and heating ones, the probes the von Mises one
CONVENTIONS = ("uqflow", "seed")
BODY_KEYS = {"rectangle": ("min", "max"), "polygon": ("vertices",),
             "circle": ("center", "radius")}
PROBE_QUANTITIES = {
    # name: (units, long name)
    "pressure": ("Pa", "EOS pressure p* (compression positive, without q)"),
    "flow_stress": ("Pa", "current flow stress sigma_y"),
    "flow_stress_total_rate": ("Pa", "Johnson-Cook flow stress at the step's total equivalent "
                                     "strain rate sqrt(2/3 D':D') (not the return's plastic "
                                     "rate), the plastic strain after the step and the "
                                     "temperature the return used: no jump between plastic "
                                     "and elastic steps"),
    "equivalent_stress": ("Pa", "von Mises stress sqrt(3/2 s:s) incl. s_zz (without s_zz "
                                "under conventions = \"seed\")"),
    "S11": ("Pa", "deviatoric stress s_xx"),
    "S22": ("Pa", "deviatoric stress s_yy"),
    "S12": ("Pa", "shear stress s_xy"),
    "S33": ("Pa", "deviatoric stress s_zz (plane strain)"),
    "plastic_strain": ("1", "equivalent plastic strain"),
    "velocity_x": ("m s-1", "particle velocity, x"),
    "velocity_y": ("m s-1", "particle velocity, y"),
    "density": ("kg m-3", "density"),
    "temperature": ("K", "temperature"),
    "burn_fraction": ("1", "burn fraction"),
    "position_x": ("m", "probe particle position, x"),
    "position_y": ("m", "probe particle position, y"),
}
DEFAULT_OUTPUTS = ("pressure", "flow_stress", "equivalent_stress", "S11", "S22", "S12",
                   "plastic_strain", "velocity_x", "velocity_y")
ENERGY_OUTPUTS = {"kinetic_energy": "J m-1", "internal_energy": "J m-1",
                  "plastic_work": "J m-1", "explosive_release": "J m-1",
                  "total_energy": "J m-1",
                  "momentum_x": "kg s-1", "momentum_y": "kg s-1"}   # per metre of thickness
# particle fields a snapshot can hold: the probe quantities (positions are the points
# themselves), the velocity as a 3-vector, and the material / body index of each particle
SNAPSHOT_FIELDS = tuple(n for n in PROBE_QUANTITIES
                        if n not in ("position_x", "position_y")) + ("velocity", "material",
                                                                      "body")
DEFAULT_SNAPSHOT_FIELDS = ("pressure", "plastic_strain", "equivalent_stress", "density",
                           "velocity", "material", "body")
SNAPSHOT_MULTIPLE_RTOL = 1e-6   # interval / output_interval must be an integer within this
EXTENT_SPEED_FACTOR = 1.25   # signal speed = factor × initial wave speed (shocks run faster)
EXTENT_MARGIN_CELLS = 4      # cells added around the domain of dependence (stencil spread)
# Upper bounds of the counts, so that what validates can run (docs/mpm.md, "Limits"):
# a particle with its grid share takes about 300 bytes (320,000 particles: ~100 MiB), so
# 2e7 lattice points are ~6 GiB and ~3 s per step at the measured 6e6 particle-updates/s.
MAX_LATTICE_POINTS = 2e7
MAX_STEPS = 10**9            # a cap on the step count; more than any run could take
MAX_THREADS = 1024           # numba threads of one run
MAX_PADDING = 64             # ghost cells per side (3 are needed by the widest stencil)
MAX_EXTENT_MARGIN = 10**6    # cells added around the domain of dependence
# A probe name becomes part of file names (the report's figures): no folder separators, no
# hidden or parent-folder names, nothing a file system or shell treats specially.
PROBE_NAME = re.compile(r"[A-Za-z0-9_.-]+")
# An averaging probe's radius, in particle spacings (cell / particles_per_cell), at least:
# below it the kernel-weighted centroid of the lattice points in the disk wanders with the
# layout by more than 0.05 spacing (0.28 at one spacing; docs/mpm.md, "Probes").
MIN_RADIUS_SPACINGS = 1.5


# ------------------------------------------------------------------------------------------
@dataclass
class Body:
    name: str
    material: str            # material label
    shape: str
    geometry: dict
    velocity: tuple


@dataclass
class Probe:
    name: str
    point: tuple
    body: str | None
    radius: float | None = None    # m; None: the nearest particle (``probe_members``)


@dataclass
class Material:
    label: str
    model: str
    module: object
    values: dict             # full parameter dict in PARAMETERS order (defaults + overrides)
    overrides: dict = field(default_factory=dict)   # what the scene set explicitly


@dataclass
class Snapshots:
    interval: float           # s, a multiple of output_interval
    every: int                # interval / output_interval: a snapshot at every every-th sample
    directory: str            # absolute (a relative scene path is taken from the cwd at parse)
    fields: tuple


@dataclass
class Config:
    grid: Grid
    ppc: int
    shape: str
    flip: float
    cfl: float
    q1: float
    q2: float
    gravity: tuple
    end_time: float
    output_interval: float
    outputs: tuple
    dt_min: float | None
    max_steps: int
    threads: int = 1          # numba threads of one run; 0: automatic (solver.SERIAL_BELOW)
    materials: dict = field(default_factory=dict)      # label -> Material
    bodies: list = field(default_factory=list)
    probes: list = field(default_factory=list)
    detonation: tuple | None = None
    cell_size: float = 0.0
    resolution: float = 1.0
    extent: str = "full"
    extent_margin: int = EXTENT_MARGIN_CELLS
    snapshots: Snapshots | None = None     # particle VTK snapshots (snapshots.py); None: off
    conventions: str = "uqflow"            # CONVENTIONS; "seed": seed 000's (docs/mpm.md)

    @property
    def times(self):
        n = int(math.floor(self.end_time / self.output_interval * (1 + 1e-12) + 1e-9)) + 1
        return self.output_interval * np.arange(n)


# ------------------------------------------------------------------------------------------
# The scene as declarations: one pydantic model per table (docs/mpm_scenes.md). A field's
# type says what it takes; its validator gives the reason of the one-line error; the
# models' own checks compare keys with each other. ``parse`` turns a validation error into
# the SceneError ``scene.<key>: <reason>`` with ``uqflow.validation.validation_error``, the
# study file's machinery.
# ------------------------------------------------------------------------------------------

class SceneProblem(ValueError):
    """What a model's check finds wrong below the table it checks: ``key`` is relative to
    that table (``"max"``, ``"[2]"``, ``"probes[1].body"``), so the error names it."""

    def __init__(self, key: str, reason: str):
        super().__init__(reason)
        self.key = key


def _number(v, *, positive=False, nonnegative=False, lo=None, hi=None) -> float:
    if not is_number(v) or not math.isfinite(v):
        raise ValueError(f"must be a finite number, got {v!r}")
    v = float(v)
    if positive and v <= 0:
        raise ValueError(f"must be > 0, got {v!r}")
    if nonnegative and v < 0:
        raise ValueError(f"must be >= 0, got {v!r}")
    if lo is not None and v < lo:
        raise ValueError(f"must be >= {lo:g}, got {v!r}")
    if hi is not None and v > hi:
        raise ValueError(f"must be <= {hi:g}, got {v!r}")
    return v


def _integer(v, *, lo, hi) -> int:
    if not isinstance(v, (int, np.integer)) or isinstance(v, bool):
        raise ValueError(f"must be an integer, got {v!r}")
    if v < lo:
        raise ValueError(f"must be >= {lo}, got {v!r}")
    if v > hi:
        raise ValueError(f"must be <= {hi:,}, got {v!r}")
    return int(v)


def _particles_per_cell(v) -> int:
    if isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v > 8:
        raise ValueError(f"is per direction; at most 8, got {v}")
    return _integer(v, lo=1, hi=8)


def _pair(v) -> tuple[float, float]:
    if (not isinstance(v, (list, tuple)) or len(v) != 2
            or not all(is_number(a) and math.isfinite(a) for a in v)):
        raise ValueError(f"must be a pair of finite numbers [a, b], got {v!r}")
    return float(v[0]), float(v[1])


def _vertices(v) -> tuple:
    if not isinstance(v, (list, tuple)) or len(v) < 3:
        raise ValueError("must list at least 3 points [x, y]")
    points = []
    for i, point in enumerate(v):
        try:
            points.append(_pair(point))
        except ValueError as exc:
            raise SceneProblem(f"[{i}]", str(exc)) from None
    return tuple(points)


def _choice(v, *, choices, quoted=False) -> str:
    if not isinstance(v, str) or v not in choices:
        shown = " or ".join(f'"{c}"' for c in choices) if quoted else ", ".join(choices)
        raise ValueError(f"must be {'' if quoted else 'one of '}{shown}, got {v!r}")
    return v


def _names(v, *, known, what) -> tuple[str, ...]:
    """A non-empty list of distinct names, each one of ``known``."""
    if not isinstance(v, (list, tuple)) or not v or not all(isinstance(o, str) for o in v):
        raise ValueError(f"must be a non-empty list of names, got {v!r}")
    for k, o in enumerate(v):
        if o not in known:
            raise SceneProblem(f"[{k}]", f"unknown {what} {o!r} (known: {', '.join(known)})")
    if len(set(v)) != len(v):
        raise ValueError("lists a name twice")
    return tuple(v)


def _text(v, *, what="a non-empty string") -> str:
    if not isinstance(v, str) or not v:
        raise ValueError(f"must be {what}, got {v!r}")
    return v


def _probe_name(v) -> str:
    if not isinstance(v, str) or not v:
        raise ValueError("is required (a non-empty string)")
    if not PROBE_NAME.fullmatch(v) or v.startswith("."):
        raise ValueError(f"{v!r} cannot name files: a probe name names its figures, so it is "
                         f"letters, digits, '_', '.' and '-' only, not starting with '.'")
    return v


def _directory(v) -> str:
    if not isinstance(v, str) or not v.strip():
        raise ValueError(f"must be a non-empty path, got {v!r}")
    return v


def _non_empty_list(v, *, what):
    if not isinstance(v, (list, tuple)) or not v:
        raise ValueError(f"must be a non-empty list of {what}")
    return tuple(v)


def _list(v, *, what):
    if not isinstance(v, (list, tuple)):
        raise ValueError(f"must be a list of {what}")
    return tuple(v)


def Number(**bounds):
    """A finite number (a TOML integer or float, not a boolean) within ``bounds``."""
    return Annotated[float, BeforeValidator(partial(_number, **bounds))]


def Integer(lo, hi):
    return Annotated[int, BeforeValidator(partial(_integer, lo=lo, hi=hi))]


def OneOf(choices, quoted=False):
    return Annotated[str, BeforeValidator(partial(_choice, choices=tuple(choices),
                                                  quoted=quoted))]


def Names(known, what):
    return Annotated[tuple[str, ...], BeforeValidator(partial(_names, known=tuple(known),
                                                              what=what))]


Pair = Annotated[tuple[float, float], BeforeValidator(_pair)]
Vertices = Annotated[tuple[tuple[float, float], ...], BeforeValidator(_vertices)]
Name = Annotated[str, BeforeValidator(_text)]
ProbeName = Annotated[str, BeforeValidator(_probe_name)]


class _Table(BaseModel):
    # Every value passes through its validator above (strict: no "2" for 2, no true for 1);
    # an unknown key is an error, not ignored.
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)


class DomainSpec(_Table):
    """``domain = { x = [low, high], y = [low, high] }`` (m)."""
    x: Pair
    y: Pair

    @model_validator(mode="after")
    def _ordered(self):
        for k in ("x", "y"):
            low, high = getattr(self, k)
            if high <= low:
                raise SceneProblem(k, "high must be above low")
        return self


class BulkViscositySpec(_Table):
    """Artificial bulk viscosity q = ρ (Q1 ℓ² (tr D)² + Q2 ℓ c |tr D|) in compression."""
    Q1: Number(nonnegative=True) = 1.5
    Q2: Number(nonnegative=True) = 0.06


class BoundariesSpec(_Table):
    """The kind of each side of the domain (grid.py)."""
    left: OneOf(SIDE_KINDS) = "free"
    right: OneOf(SIDE_KINDS) = "free"
    bottom: OneOf(SIDE_KINDS) = "free"
    top: OneOf(SIDE_KINDS) = "free"


class ClampSpec(_Table):
    """A rectangle of grid nodes held at rest."""
    min: Pair
    max: Pair

    @model_validator(mode="after")
    def _ordered(self):
        if self.max[0] < self.min[0] or self.max[1] < self.min[1]:
            raise SceneProblem("max", "must not be below min")
        return self


def _flatten(tbl, prefix=""):
    """Nested tables to dotted names: {"jc": {"A": 1}} → {"jc.A": 1}."""
    out = {}
    for k, v in tbl.items():
        name = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(_flatten(v, name + "."))
        else:
            out[name] = v
    return out


class MaterialSpec(_Table):
    """``materials.<label> = { model = "<library name>", <parameter> = value, ... }``: a
    library material with some parameters set (nested tables are dotted names:
    ``jc = { A = 7.9e8 }`` is ``jc.A``)."""
    model_config = ConfigDict(extra="allow", strict=True, frozen=True)
    model: str

    @field_validator("model", mode="before")
    @classmethod
    def _known(cls, v):
        lib = _library()
        if not isinstance(v, str) or v not in lib:
            raise ValueError(f"unknown material {v!r} (known: {', '.join(sorted(lib))})")
        return v

    @model_validator(mode="after")
    def _parameters(self):
        params = library_parameters(self.model)
        for name, v in self.overrides().items():
            if name not in params:
                raise SceneProblem(name, f"material {self.model!r} has no parameter {name!r} "
                                         f"(takes {', '.join(params)})")
            try:
                _number(v)
            except ValueError as exc:
                raise SceneProblem(name, str(exc)) from None
        return self

    def overrides(self) -> dict:
        """The parameters the scene sets, by dotted name, as written."""
        return _flatten(self.model_extra or {})


class BodySpec(_Table):
    """One body: a rectangle (``min``, ``max``), a polygon (``vertices``) or a circle
    (``center``, ``radius``) of one material, with an initial velocity. A lattice point
    belongs to the first body that holds it."""
    name: Name = None                  # None: "body<k>", k its place in the list
    material: Annotated[str, BeforeValidator(partial(_text, what="a name"))]
    shape: str
    velocity: Pair = (0.0, 0.0)
    min: Pair = None
    max: Pair = None
    vertices: Vertices = None
    center: Pair = None
    radius: Number(positive=True) = None

    @model_validator(mode="before")
    @classmethod
    def _keys_of_its_shape(cls, v):
        if not isinstance(v, Mapping):
            return v
        shape = v.get("shape")
        if not isinstance(shape, str) or shape not in BODY_KEYS:
            raise SceneProblem("shape", f"must be one of {', '.join(BODY_KEYS)}, got {shape!r}")
        takes = ("name", "material", "shape", "velocity") + BODY_KEYS[shape]
        for k in v:
            if k not in takes:
                raise SceneProblem(str(k), f"unknown key (a {shape} takes "
                                           f"{', '.join(sorted(takes))})")
        for k in ("material",) + BODY_KEYS[shape]:
            if k not in v:
                raise SceneProblem(k, "is required")
        return v

    @model_validator(mode="after")
    def _rectangle_ordered(self):
        if self.shape == "rectangle" and (self.max[0] <= self.min[0]
                                          or self.max[1] <= self.min[1]):
            raise SceneProblem("max", "must be above min in x and y")
        return self

    def geometry(self) -> dict:
        if self.shape == "rectangle":
            return {"min": self.min, "max": self.max}
        if self.shape == "circle":
            return {"center": self.center, "radius": self.radius}
        return {"vertices": np.array(self.vertices)}

    def box(self) -> tuple[float, float, float, float]:
        """(x low, y low, x high, y high) of the body."""
        if self.shape == "rectangle":
            return (*self.min, *self.max)
        if self.shape == "circle":
            (cx, cy), r = self.center, self.radius
            return cx - r, cy - r, cx + r, cy + r
        v = np.array(self.vertices)
        return (*v.min(axis=0), *v.max(axis=0))


class DetonationSpec(_Table):
    """Where the explosive is lit (m)."""
    point: Pair


class ProbeSpec(_Table):
    """A gauge: the particle of ``body`` (any body) nearest ``point`` at t = 0, or with
    ``radius`` the weighted average of that body's particles within it (docs/mpm.md)."""
    name: ProbeName
    point: Pair
    body: Annotated[str, BeforeValidator(partial(_text, what="a body name"))] = None
    radius: Number(positive=True) = None


class SnapshotsSpec(_Table):
    """Particle VTK files every ``interval`` (a multiple of output_interval) into
    ``directory``, holding ``fields`` (snapshots.py)."""
    interval: Number(positive=True)
    directory: Annotated[str, BeforeValidator(_directory)]
    fields: Names(SNAPSHOT_FIELDS, "field") = DEFAULT_SNAPSHOT_FIELDS


class SceneSpec(_Table):
    """An MPM scene (docs/mpm_scenes.md has every key)."""
    domain: DomainSpec
    cell_size: Number(positive=True)
    resolution: Number(positive=True) = 1.0
    particles_per_cell: Annotated[int, BeforeValidator(_particles_per_cell)] = 2
    shape: OneOf(KINDS) = "quadratic"
    flip: Number(lo=0.0, hi=1.0) = 1.0
    cfl: Number(positive=True, hi=1.0) = 0.3
    bulk_viscosity: BulkViscositySpec = BulkViscositySpec()
    gravity: Pair = (0.0, 0.0)
    end_time: Number(positive=True)
    output_interval: Number(positive=True) = None      # None: end_time / 100
    dt_min: Number(positive=True) = None
    max_steps: Integer(1, MAX_STEPS) = 5_000_000
    threads: Integer(0, MAX_THREADS) = 1
    padding: Integer(2, MAX_PADDING) = 3
    extent: OneOf(("full", "auto"), quoted=True) = "full"
    extent_margin: Integer(0, MAX_EXTENT_MARGIN) = EXTENT_MARGIN_CELLS
    outputs: Names(PROBE_QUANTITIES, "output") = DEFAULT_OUTPUTS
    conventions: str = "uqflow"
    boundaries: BoundariesSpec = BoundariesSpec()
    clamps: Annotated[tuple[ClampSpec, ...], BeforeValidator(partial(
        _list, what="tables {min = [x, y], max = [x, y]}"))] = ()
    materials: dict[str, MaterialSpec] = {}
    bodies: Annotated[tuple[BodySpec, ...], BeforeValidator(partial(
        _non_empty_list, what="tables"))]
    detonation: DetonationSpec = None
    probes: Annotated[tuple[ProbeSpec, ...], BeforeValidator(partial(
        _list, what="tables {name, point, body, radius}"))] = ()
    snapshots: SnapshotsSpec = None

    @field_validator("conventions", mode="before")
    @classmethod
    def _conventions(cls, v):
        if not isinstance(v, str) or v not in CONVENTIONS:
            raise ValueError(f"must be one of {', '.join(map(repr, CONVENTIONS))}, got {v!r}")
        return v

    @field_validator("materials", mode="before")
    @classmethod
    def _labels(cls, v):
        if isinstance(v, Mapping):
            for label in v:
                if not isinstance(label, str) or not label.isidentifier():
                    raise SceneProblem(f".{label}", "a material label must be a name "
                                                    "(letters, digits, _)")
        return v

    @property
    def sample_interval(self) -> float:
        return self.end_time / 100.0 if self.output_interval is None else self.output_interval

    @property
    def cell(self) -> float:
        """The grid's cell size: cell_size / resolution."""
        return self.cell_size / self.resolution

    @model_validator(mode="after")
    def _consistent(self):
        """What one key says about another: times, the lattice's size, names that refer to
        materials and bodies, probe radii, the snapshot interval."""
        end, dt_out = self.end_time, self.sample_interval
        if dt_out > end:
            raise SceneProblem("output_interval", f"{dt_out:g} s is longer than end_time "
                                                  f"{end:g} s")
        if end / dt_out > 1e6:
            raise SceneProblem("output_interval", "more than 10^6 samples")
        (x0, x1), (y0, y1) = self.domain.x, self.domain.y
        dx, ppc = self.cell, self.particles_per_cell
        # Seeding lays a lattice of ppc × ppc points over every cell before keeping those in
        # a body: bound it before anything is allocated (floats: no integer overflow first).
        lattice = ((x1 - x0) / dx + 1) * ((y1 - y0) / dx + 1) * float(ppc) ** 2
        if lattice > MAX_LATTICE_POINTS:
            raise SceneProblem("resolution" if "resolution" in self.model_fields_set
                               else "cell_size",
                               f"the domain holds {lattice:.3g} lattice points (cells × "
                               f"particles_per_cell²) at cell size {dx:g} m; at most "
                               f"{MAX_LATTICE_POINTS:.0e} fit in memory (about 300 bytes each)")
        lib = _library()
        names = []
        for k, body in enumerate(self.bodies):
            name = body_name(body, k)
            if name in names:
                raise SceneProblem(f"bodies[{k}].name", f"duplicate body name {name!r}")
            names.append(name)
            if body.material not in self.materials and body.material not in lib:
                raise SceneProblem(f"bodies[{k}].material",
                                   f"unknown material {body.material!r} (scene materials: "
                                   f"{', '.join(self.materials) or 'none'}; library: "
                                   f"{', '.join(sorted(lib))})")
        seen = set()
        for k, probe in enumerate(self.probes):
            if probe.name in seen:
                raise SceneProblem(f"probes[{k}].name", f"duplicate probe name {probe.name!r}")
            seen.add(probe.name)
            if probe.body is not None and probe.body not in names:
                raise SceneProblem(f"probes[{k}].body", f"no body named {probe.body!r} "
                                                        f"(bodies: {', '.join(names)})")
            spacing = dx / ppc
            if probe.radius is not None and probe.radius < MIN_RADIUS_SPACINGS * spacing:
                raise SceneProblem(
                    f"probes[{k}].radius",
                    f"{probe.radius:g} m is less than {MIN_RADIUS_SPACINGS:g} particle "
                    f"spacings ({MIN_RADIUS_SPACINGS * spacing:g} m at cell {dx:g} m, {ppc} "
                    f"particles per cell): the average would move with the particle layout; "
                    f"drop radius for the nearest particle")
        if self.snapshots is not None:
            ratio = self.snapshots.interval / dt_out
            every = round(ratio)
            if every < 1 or abs(ratio - every) > SNAPSHOT_MULTIPLE_RTOL * every:
                raise SceneProblem("snapshots.interval",
                                   f"must be a multiple of output_interval = {dt_out:g} s (the "
                                   f"state is sampled at output times only), got "
                                   f"{self.snapshots.interval:g} s = {ratio:.6g} x "
                                   f"output_interval")
        return self


def _err(key: str, reason: str) -> SceneError:
    """The one-line error of a scene value found wrong after validation (``scene.<key>``)."""
    return SceneError(reason, key=f"scene.{key}")


def body_name(body: BodySpec, k: int) -> str:
    """A body's name: its own, else ``body<k>`` after its place in the scene's list."""
    return f"body{k}" if body.name is None else body.name


def _library():
    from solvers.mpm.materials.library import MATERIALS
    return MATERIALS


def library_parameters(model: str) -> dict:
    """A library material's parameters with their values: the model's defaults, then the
    library entry's."""
    module, defaults = _library()[model]
    params = dict(module.PARAMETERS)
    params.update(defaults or {})
    return params


def scene_error(exc: ValidationError, data) -> SceneError:
    """The first problem of a scene's validation as the one-line SceneError naming
    ``scene.<key>`` (the key as the user wrote it; a SceneProblem's own key appended)."""
    error = validation_error(exc, "", prefix="scene", data=data, model=SceneSpec)
    key, reason = error.key or "scene", error.reason
    problem = exc.errors()[0].get("ctx", {}).get("error")
    if isinstance(problem, SceneProblem):
        key += problem.key if problem.key.startswith(("[", ".")) else f".{problem.key}"
        reason = str(problem)
    return SceneError(reason, key=key)


def validate(scene) -> SceneSpec:
    """The scene table as a ``SceneSpec`` (raises the one-line ``SceneError``)."""
    if not isinstance(scene, Mapping):
        raise SceneError("must be a table", key="scene")
    try:
        return SceneSpec.model_validate(dict(scene))
    except ValidationError as exc:
        raise scene_error(exc, dict(scene)) from None


def parse(scene) -> Config:
    """Validate a scene table (``validate``) and build the run's ``Config``: the grid, the
    materials the bodies use (scene materials in the scene's order, then library names used
    directly, in body order), the bodies, probes and snapshots. Raises ``SceneError``."""
    spec = validate(scene)
    (x0, x1), (y0, y1) = spec.domain.x, spec.domain.y
    dx, pad = spec.cell, spec.padding
    sides = spec.boundaries.model_dump()
    clamps = [(*c.min, *c.max) for c in spec.clamps]
    grid = Grid.cover(x0, x1, y0, y1, dx, pad, sides, clamps)
    if (any(v not in ("free", "absorbing") for v in sides.values())
            and min(grid.ncx, grid.ncy) < 2 * pad):
        raise _err("boundaries", f"a fixed, roller or symmetry side needs a domain of at least "
                                 f"2 x padding = {2 * pad} cells across")

    materials = {label: _material(label, m.model, m.overrides())
                 for label, m in spec.materials.items()}
    bodies = []
    tol = 1e-9 * max(x1 - x0, y1 - y0)
    for k, b in enumerate(spec.bodies):
        if b.material not in materials:         # a library name used directly as a label
            materials[b.material] = _material(b.material, b.material, {})
        box = b.box()
        if box[0] < x0 - tol or box[1] < y0 - tol or box[2] > grid.x1 + tol or \
                box[3] > grid.y1 + tol:
            raise _err(f"bodies[{k}]", f"extends outside the domain [{x0:g}, {grid.x1:g}] x "
                                       f"[{y0:g}, {grid.y1:g}]")
        bodies.append(Body(body_name(b, k), b.material, b.shape, b.geometry(), b.velocity))
    used = {b.material for b in bodies}
    materials = {label: m for label, m in materials.items() if label in used}
    probes = [Probe(p.name, p.point, p.body, p.radius) for p in spec.probes]
    dt_out = spec.sample_interval
    snaps = None
    if spec.snapshots is not None:
        every = round(spec.snapshots.interval / dt_out)
        snaps = Snapshots(interval=every * dt_out, every=int(every),
                          directory=os.path.abspath(os.path.expanduser(
                              spec.snapshots.directory)),
                          fields=tuple(spec.snapshots.fields))
    materials = apply_conventions(materials, spec.conventions)
    _check_material_constants(materials)
    return Config(grid=grid, ppc=spec.particles_per_cell, shape=spec.shape, flip=spec.flip,
                  cfl=spec.cfl, q1=spec.bulk_viscosity.Q1, q2=spec.bulk_viscosity.Q2,
                  gravity=spec.gravity, end_time=spec.end_time, output_interval=dt_out,
                  outputs=tuple(spec.outputs), dt_min=spec.dt_min, max_steps=spec.max_steps,
                  threads=spec.threads, materials=materials, bodies=bodies, probes=probes,
                  detonation=None if spec.detonation is None else spec.detonation.point,
                  cell_size=spec.cell_size, resolution=spec.resolution, extent=spec.extent,
                  extent_margin=spec.extent_margin, snapshots=snaps,
                  conventions=spec.conventions)


def _material(label, model, overrides) -> Material:
    """A library material with the scene's ``overrides`` (validated by ``MaterialSpec``)."""
    module, _ = _library()[model]
    values = library_parameters(model)
    values.update({name: float(v) for name, v in overrides.items()})
    return Material(label, model, module, values, dict(overrides))


def apply_conventions(materials: dict, conventions: str) -> dict:
    """The materials with the scene's ``conventions`` mapped onto those that have a
    conventions flag (the Johnson–Cook steel): ``seed_conventions`` = 1 under "seed", with
    ε̇0 = 1e6 /s (the seed's 1/µs) unless the scene sets ``jc.eps0_dot`` itself. The flag
    belongs to the scene, so a material may not set it. Applying it twice changes nothing."""
    from solvers.mpm.materials.johnson_cook import CONVENTIONS_PARAMETER, SEED_EPS0_DOT

    seed = conventions == "seed"
    out = {}
    for label, m in materials.items():
        if CONVENTIONS_PARAMETER in m.module.PARAMETERS:
            if CONVENTIONS_PARAMETER in m.overrides:
                raise _err(f"materials.{label}.{CONVENTIONS_PARAMETER}",
                           "is set by the scene's `conventions` (\"uqflow\" or \"seed\"), "
                           "not per material")
            values = dict(m.values)
            values[CONVENTIONS_PARAMETER] = 1.0 if seed else 0.0
            if seed and "jc.eps0_dot" not in m.overrides:
                values["jc.eps0_dot"] = SEED_EPS0_DOT
            m = Material(m.label, m.model, m.module, values, dict(m.overrides))
        out[label] = m
    return out


def _check_material_constants(materials: dict) -> None:
    """Every material's parameters, as the scene sets them under its conventions, in their
    ranges: a constant that every run would refuse (say jc.C = 0.05 under the seed
    conventions, whose rate factor needs C < 0.048) is refused here, at load, under its key.
    A sampled value out of range still fails only its realization."""
    from solvers.mpm.materials.state import ParameterError

    for label, m in materials.items():
        try:
            m.module.pack(m.values)
        except ParameterError as exc:
            raise _err(f"materials.{label}.{exc.parameter}", exc.reason) from None


# ------------------------------------------------------------------------------------------
# Particles
# ------------------------------------------------------------------------------------------

def _inside(body, x, y):
    g = body.geometry
    if body.shape == "rectangle":
        (a, b), (c, d) = g["min"], g["max"]
        return (x >= a) & (x <= c) & (y >= b) & (y <= d)
    if body.shape == "circle":
        cx, cy = g["center"]
        return (x - cx) ** 2 + (y - cy) ** 2 <= g["radius"] ** 2
    v = g["vertices"]
    inside = np.zeros(x.shape, dtype=bool)
    n = len(v)
    for k in range(n):                       # even-odd rule, vectorised over the points
        xa, ya = v[k]
        xb, yb = v[(k + 1) % n]
        cross = (ya > y) != (yb > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = xa + (y - ya) * (xb - xa) / (yb - ya)
        inside ^= cross & (x < xc)
    return inside


@dataclass
class Particles:
    x: np.ndarray
    y: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    vol0: np.ndarray
    body: np.ndarray          # body index
    material: np.ndarray      # material index (order of cfg.materials)


def seed_particles(cfg: Config) -> Particles:
    """``ppc × ppc`` particles per cell on a regular lattice over the domain's cells; a
    lattice point belongs to the first body (in scene order) that contains it; points in no
    body make no particle. Particles are sorted by material, then by lattice order."""
    g = cfg.grid
    n = cfg.ppc
    h = g.dx / n
    ox, oy = g.x0 - g.ci0 * g.dx, g.y0 - g.cj0 * g.dx       # the full grid's corner
    xs = ox + h * (np.arange(g.ci0 * n, (g.ci0 + g.ncx) * n) + 0.5)
    ys = oy + h * (np.arange(g.cj0 * n, (g.cj0 + g.ncy) * n) + 0.5)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    X, Y = X.ravel(), Y.ravel()
    owner = np.full(X.size, -1, dtype=np.int64)
    for k, body in enumerate(cfg.bodies):
        free = owner < 0
        owner[free & _inside(body, X, Y)] = k
    keep = owner >= 0
    X, Y, owner = X[keep], Y[keep], owner[keep]
    labels = list(cfg.materials)
    body_mat = np.array([labels.index(b.material) for b in cfg.bodies], dtype=np.int64)
    mat = body_mat[owner]
    order = np.argsort(mat, kind="stable")
    X, Y, owner, mat = X[order], Y[order], owner[order], mat[order]
    vel = np.array([b.velocity for b in cfg.bodies]).reshape(-1, 2)
    return Particles(x=X.copy(), y=Y.copy(), vx=vel[owner, 0].copy(), vy=vel[owner, 1].copy(),
                     vol0=np.full(X.size, h * h), body=owner, material=mat)


def place_probes(cfg: Config, parts: Particles) -> np.ndarray:
    """Particle index of each probe: the particle of the probe's body (any body when none is
    named) nearest to the probe point in the initial configuration (a Lagrangian gauge that
    then moves with the material; ties to the lowest index). A probe farther than one cell
    from every candidate is a SceneError (the point is not in that body)."""
    idx = np.zeros(len(cfg.probes), dtype=np.int64)
    names = [b.name for b in cfg.bodies]
    for k, p in enumerate(cfg.probes):
        cand = np.arange(parts.x.size)
        if p.body is not None:
            cand = cand[parts.body == names.index(p.body)]
        if cand.size == 0:
            raise _err(f"probes[{k}].body", f"body {p.body!r} has no particles")
        d2 = (parts.x[cand] - p.point[0]) ** 2 + (parts.y[cand] - p.point[1]) ** 2
        # ties (a point midway between lattice points) go to the lowest index, whatever the
        # round-off of the positions
        j = int(np.flatnonzero(d2 <= d2.min() + 1e-9 * cfg.grid.dx ** 2)[0])
        if math.sqrt(d2[j]) > cfg.grid.dx:
            raise _err(f"probes[{k}].point", f"({p.point[0]:g}, {p.point[1]:g}) is "
                       f"{math.sqrt(d2[j]):.3g} m from the nearest particle of "
                       f"{p.body or 'any body'} (more than one cell)")
        idx[k] = cand[j]
    return idx


def probe_weights(distance, radius):
    """Averaging weights of particles at initial ``distance`` < ``radius`` from a probe point,
    normalised to sum 1: the kernel (1 − (r/R)²)³. Its value, slope and curvature vanish at
    r = R, so a particle that refinement moves across the rim enters with a weight of order
    (h/R)³ instead of a jump (a top-hat average keeps a layout error of 0.2–0.4 spacings in
    its centroid); inside it is a polynomial in r², smooth at the point itself."""
    q2 = (np.asarray(distance, dtype=float) / radius) ** 2
    w = (1.0 - q2) ** 3
    return w / w.sum()


def probe_members(cfg: Config, parts: Particles, probe_index=None) -> list:
    """``[(particle indices, weights)]``, one pair per probe, fixed at t = 0: a probe value is
    Σ w · (the particle's value). A probe without ``radius`` is its nearest particle
    (``place_probes``), ``(array([i]), array([1.0]))``. A probe with ``radius`` R averages the
    particles of its body — the named one, else the nearest particle's — whose initial
    distance to the point is below R, weighted by ``probe_weights``; particles of other
    bodies never enter (a disk reaching past the plate averages steel only). The members are
    a Lagrangian set: they move with the material and stay the same for the whole run."""
    if probe_index is None:
        probe_index = place_probes(cfg, parts)
    out = []
    for k, (p, i) in enumerate(zip(cfg.probes, probe_index)):
        i = int(i)
        if p.radius is None:
            out.append((np.array([i], dtype=np.int64), np.array([1.0])))
            continue
        cand = np.flatnonzero(parts.body == parts.body[i])
        dist = np.hypot(parts.x[cand] - p.point[0], parts.y[cand] - p.point[1])
        inside = dist < p.radius
        if not inside.any():
            body = cfg.bodies[int(parts.body[i])].name
            raise _err(f"probes[{k}].radius", f"no particle of body {body!r} lies within "
                       f"{p.radius:g} m of ({p.point[0]:g}, {p.point[1]:g}) (the nearest is "
                       f"{float(dist.min()):.3g} m away)")
        out.append((cand[inside].astype(np.int64), probe_weights(dist[inside], p.radius)))
    return out


# ------------------------------------------------------------------------------------------
# Domain of dependence (extent = "auto")
# ------------------------------------------------------------------------------------------

def auto_extent(cfg: Config, parts: Particles, speed_of_material, probe_index):
    """The smallest grid-aligned rectangle holding every cell from which a signal can reach
    a probe before ``end_time``, plus ``extent_margin`` cells; returns (Config, info).

    Signal speed of a cell: EXTENT_SPEED_FACTOR × the largest initial wave speed (the
    materials' C after ``init``: longitudinal speed, D for an explosive) of its particles,
    plus the largest initial particle speed; empty cells carry nothing. Travel times from the
    probes' cells: Dijkstra on the 8-connected cell graph, an edge taking half its length at
    each cell's speed. Cropped sides become ``symmetry`` planes (frictionless rigid walls):
    whatever a cropped side does cannot reach a probe before ``end_time``, and a wall keeps
    the material there on the grid (through a ``free`` cut, water pushed by the products
    left the padded grid of the seed-size scene at 80 µs); sides that stay at the scene's
    boundary keep their kind.
    """
    import heapq

    g = cfg.grid
    ncx, ncy = g.ncx, g.ncy
    ci = np.clip(((parts.x - g.x0) / g.dx).astype(np.int64), 0, ncx - 1)
    cj = np.clip(((parts.y - g.y0) / g.dx).astype(np.int64), 0, ncy - 1)
    vmax = float(np.max(np.hypot(parts.vx, parts.vy))) if parts.x.size else 0.0
    sp = EXTENT_SPEED_FACTOR * np.asarray(speed_of_material, dtype=float)[parts.material] + vmax
    speed = np.zeros((ncx, ncy))
    np.maximum.at(speed, (ci, cj), sp)
    T = cfg.end_time
    tt = np.full((ncx, ncy), np.inf)
    heap = []
    # every particle a probe averages is a source of the domain of dependence
    sources = np.union1d(np.asarray(probe_index, dtype=np.int64),
                         np.concatenate([m[0] for m in probe_members(cfg, parts, probe_index)]
                                        + [np.zeros(0, dtype=np.int64)]))
    for p in sources:
        a, b = int(ci[p]), int(cj[p])
        tt[a, b] = 0.0
        heap.append((0.0, a, b))
    heapq.heapify(heap)
    steps = [(1, 0, 1.0), (-1, 0, 1.0), (0, 1, 1.0), (0, -1, 1.0), (1, 1, math.sqrt(2)),
             (1, -1, math.sqrt(2)), (-1, 1, math.sqrt(2)), (-1, -1, math.sqrt(2))]
    dx = g.dx
    while heap:
        t, a, b = heapq.heappop(heap)
        if t > tt[a, b] or t > T:
            continue
        sa = speed[a, b]
        if sa <= 0.0:
            continue
        for da, db, length in steps:
            c, d = a + da, b + db
            if 0 <= c < ncx and 0 <= d < ncy:
                sb = speed[c, d]
                if sb <= 0.0:
                    continue
                t2 = t + 0.5 * length * dx * (1.0 / sa + 1.0 / sb)
                if t2 < tt[c, d] and t2 <= T:
                    tt[c, d] = t2
                    heapq.heappush(heap, (t2, c, d))
    reach = np.isfinite(tt)
    ii = np.flatnonzero(reach.any(axis=1))
    jj = np.flatnonzero(reach.any(axis=0))
    m = cfg.extent_margin
    i0, i1 = max(0, int(ii[0]) - m), min(ncx, int(ii[-1]) + 1 + m)
    j0, j1 = max(0, int(jj[0]) - m), min(ncy, int(jj[-1]) + 1 + m)
    need = 2 * g.pad + 1              # the image folds need a few cells across
    while i1 - i0 < min(need, ncx):
        i0, i1 = max(0, i0 - 1), min(ncx, i1 + 1)
    while j1 - j0 < min(need, ncy):
        j0, j1 = max(0, j0 - 1), min(ncy, j1 + 1)
    sides = dict(g.sides)
    if i0 > 0:
        sides["left"] = "symmetry"
    if i1 < ncx:
        sides["right"] = "symmetry"
    if j0 > 0:
        sides["bottom"] = "symmetry"
    if j1 < ncy:
        sides["top"] = "symmetry"
    grid = Grid(g.x0 + i0 * dx, g.y0 + j0 * dx, dx, i1 - i0, j1 - j0, g.pad, sides,
                list(g.clamps), g.ci0 + i0, g.cj0 + j0)
    import dataclasses
    new = dataclasses.replace(cfg, grid=grid)
    info = {"extent_cells": int(grid.cells), "full_cells": int(g.cells),
            "cells_saved": int(g.cells - grid.cells),
            "extent": (grid.x0, grid.x1, grid.y0, grid.y1)}
    return new, info
