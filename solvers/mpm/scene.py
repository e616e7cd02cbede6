"""Scene schema of the MPM solver: validation (``SceneError`` naming ``scene.<key>``), particle
seeding and probe placement. Numerics live in ``step.py``; the run in ``solver.py``.

Scene keys (docs/mpm.md, "Scene"): ``domain``, ``cell_size``, ``resolution``,
``particles_per_cell``, ``shape``, ``flip``, ``cfl``, ``bulk_viscosity``, ``gravity``,
``end_time``, ``output_interval``, ``outputs``, ``dt_min``, ``padding``, ``extent``,
``materials``, ``bodies``, ``detonation``, ``boundaries``, ``clamps``, ``probes``,
``snapshots`` (particle VTK files, ``snapshots.py``; docs/mpm_scenes.md), ``conventions``
(``"uqflow"`` or ``"seed"``: docs/mpm.md, "Conventions").
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from solvers.mpm.grid import SIDE_KINDS, SIDES, Grid
from solvers.mpm.shapes import KINDS
from uqflow.errors import SceneError
from uqflow.scene_checks import (check_keys, integer, is_number, number, number_pair,
                                 scene_error, table)

TOP_KEYS = ("domain", "cell_size", "resolution", "particles_per_cell", "shape", "flip", "cfl",
            "bulk_viscosity", "gravity", "end_time", "output_interval", "outputs", "dt_min",
            "padding", "extent", "materials", "bodies", "detonation", "boundaries", "clamps",
            "probes", "max_steps", "threads", "extent_margin", "snapshots", "conventions")
# "seed": the conventions under which seed 000's tables are reproduced (docs/mpm.md,
# "Conventions"); the kernels read the rate and heating ones, the probes the von Mises one
CONVENTIONS = ("uqflow", "seed")
REQUIRED = ("domain", "cell_size", "bodies", "end_time")
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
SNAPSHOT_KEYS = ("interval", "directory", "fields")
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
DEFAULTS = {"resolution": 1.0, "particles_per_cell": 2, "shape": "quadratic", "flip": 1.0,
            "cfl": 0.3, "gravity": [0.0, 0.0], "padding": 3, "extent": "full",
            "max_steps": 5_000_000, "threads": 1, "conventions": "uqflow"}
PROBE_KEYS = ("name", "point", "body", "radius")
# A probe name becomes part of file names (the report's figures): no folder separators, no
# hidden or parent-folder names, nothing a file system or shell treats specially.
PROBE_NAME = re.compile(r"[A-Za-z0-9_.-]+")
# An averaging probe's radius, in particle spacings (cell / particles_per_cell), at least:
# below it the kernel-weighted centroid of the lattice points in the disk wanders with the
# layout by more than 0.05 spacing (0.28 at one spacing; docs/mpm.md, "Probes").
MIN_RADIUS_SPACINGS = 1.5


_is_number, _err, _num, _int = is_number, scene_error, number, integer
_pair, _table, _keys = number_pair, table, check_keys


def _names(v, key, known, what):
    """A non-empty list of distinct names, each one of ``known``."""
    if not isinstance(v, (list, tuple)) or not v or not all(isinstance(o, str) for o in v):
        raise _err(key, f"must be a non-empty list of names, got {v!r}")
    for k, o in enumerate(v):
        if o not in known:
            raise _err(f"{key}[{k}]", f"unknown {what} {o!r} (known: {', '.join(known)})")
    if len(set(v)) != len(v):
        raise _err(key, "lists a name twice")
    return list(v)


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


def _library():
    from solvers.mpm.materials.library import MATERIALS
    return MATERIALS


def parse(scene) -> Config:
    """Validate a scene table; returns the ``Config`` (raises ``SceneError``)."""
    if not isinstance(scene, Mapping):
        raise SceneError("must be a table", key="scene")
    _keys(scene, TOP_KEYS, "")
    for k in REQUIRED:
        if k not in scene:
            raise _err(k, "is required")
    s = dict(DEFAULTS)
    s.update(scene)

    dom = _table(s["domain"], "domain")
    _keys(dom, ("x", "y"), "domain")
    for k in ("x", "y"):
        if k not in dom:
            raise _err(f"domain.{k}", "is required ([low, high], m)")
    x0, x1 = _pair(dom["x"], "domain.x")
    y0, y1 = _pair(dom["y"], "domain.y")
    if x1 <= x0:
        raise _err("domain.x", "high must be above low")
    if y1 <= y0:
        raise _err("domain.y", "high must be above low")
    cell = _num(s["cell_size"], "cell_size", positive=True)
    res = _num(s["resolution"], "resolution", positive=True)
    dx = cell / res
    ppc = s["particles_per_cell"]
    if isinstance(ppc, (int, np.integer)) and not isinstance(ppc, bool) and ppc > 8:
        raise _err("particles_per_cell", f"is per direction; at most 8, got {ppc}")
    ppc = _int(ppc, "particles_per_cell", 1, 8)
    shape = s["shape"]
    if not isinstance(shape, str) or shape not in KINDS:
        raise _err("shape", f"must be one of {', '.join(KINDS)}, got {shape!r}")
    flip = _num(s["flip"], "flip", lo=0.0, hi=1.0)
    cfl = _num(s["cfl"], "cfl", positive=True, hi=1.0)
    q1, q2 = 1.5, 0.06
    if "bulk_viscosity" in s:
        bv = _table(s["bulk_viscosity"], "bulk_viscosity")
        _keys(bv, ("Q1", "Q2"), "bulk_viscosity")
        q1 = _num(bv.get("Q1", q1), "bulk_viscosity.Q1", nonnegative=True)
        q2 = _num(bv.get("Q2", q2), "bulk_viscosity.Q2", nonnegative=True)
    gravity = _pair(s["gravity"], "gravity")
    end = _num(s["end_time"], "end_time", positive=True)
    dt_out = _num(s.get("output_interval", end / 100.0), "output_interval", positive=True)
    if dt_out > end:
        raise _err("output_interval", f"{dt_out:g} s is longer than end_time {end:g} s")
    if end / dt_out > 1e6:
        raise _err("output_interval", "more than 10^6 samples")
    dt_min = None
    if "dt_min" in s:
        dt_min = _num(s["dt_min"], "dt_min", positive=True)
    max_steps = _int(s["max_steps"], "max_steps", 1, MAX_STEPS)
    threads = _int(s["threads"], "threads", 0, MAX_THREADS)
    pad = _int(s["padding"], "padding", 2, MAX_PADDING)
    extent = s["extent"]
    if not isinstance(extent, str) or extent not in ("full", "auto"):
        raise _err("extent", f"must be \"full\" or \"auto\", got {extent!r}")
    margin = 0
    if "extent_margin" in s:
        margin = _int(s["extent_margin"], "extent_margin", 0, MAX_EXTENT_MARGIN)
    else:
        margin = EXTENT_MARGIN_CELLS

    outs = _names(s.get("outputs", list(DEFAULT_OUTPUTS)), "outputs", PROBE_QUANTITIES,
                  "output")
    conventions = s["conventions"]
    if not isinstance(conventions, str) or conventions not in CONVENTIONS:
        raise _err("conventions", f"must be one of {', '.join(map(repr, CONVENTIONS))}, "
                                  f"got {conventions!r}")

    # boundaries ---------------------------------------------------------------------------
    sides = dict.fromkeys(SIDES, "free")
    if "boundaries" in s:
        b = _table(s["boundaries"], "boundaries")
        _keys(b, SIDES, "boundaries")
        for k, v in b.items():
            if not isinstance(v, str) or v not in SIDE_KINDS:
                raise _err(f"boundaries.{k}", f"must be one of {', '.join(SIDE_KINDS)}, "
                                              f"got {v!r}")
            sides[k] = v
    clamps = []
    if "clamps" in s:
        cl = s["clamps"]
        if not isinstance(cl, (list, tuple)):
            raise _err("clamps", "must be a list of tables {min = [x, y], max = [x, y]}")
        for k, c in enumerate(cl):
            key = f"clamps[{k}]"
            c = _table(c, key)
            _keys(c, ("min", "max"), key)
            for kk in ("min", "max"):
                if kk not in c:
                    raise _err(f"{key}.{kk}", "is required")
            lo = _pair(c["min"], f"{key}.min")
            hi = _pair(c["max"], f"{key}.max")
            if hi[0] < lo[0] or hi[1] < lo[1]:
                raise _err(f"{key}.max", "must not be below min")
            clamps.append((lo[0], lo[1], hi[0], hi[1]))
    # Seeding lays a lattice of ppc × ppc points over every cell before keeping those in a
    # body: bound it before anything is allocated (floats, so no integer overflows first).
    lattice = ((x1 - x0) / dx + 1) * ((y1 - y0) / dx + 1) * float(ppc) ** 2
    if lattice > MAX_LATTICE_POINTS:
        raise _err("cell_size" if "resolution" not in scene else "resolution",
                   f"the domain holds {lattice:.3g} lattice points (cells × "
                   f"particles_per_cell²) at cell size {dx:g} m; at most "
                   f"{MAX_LATTICE_POINTS:.0e} fit in memory (about 300 bytes each)")
    grid = Grid.cover(x0, x1, y0, y1, dx, pad, sides, clamps)
    if (any(v not in ("free", "absorbing") for v in sides.values())
            and min(grid.ncx, grid.ncy) < 2 * pad):
        raise _err("boundaries", f"a fixed, roller or symmetry side needs a domain of at least "
                                 f"2 x padding = {2 * pad} cells across")

    # materials ----------------------------------------------------------------------------
    lib = _library()
    materials = {}
    mats = s.get("materials", {})
    mats = _table(mats, "materials")
    for label, spec in mats.items():
        key = f"materials.{label}"
        if not isinstance(label, str) or not label.isidentifier():
            raise _err(key, "a material label must be a name (letters, digits, _)")
        spec = _table(spec, key)
        if "model" not in spec:
            raise _err(f"{key}.model", f"is required (one of {', '.join(sorted(lib))})")
        model = spec["model"]
        if not isinstance(model, str) or model not in lib:
            raise _err(f"{key}.model", f"unknown material {model!r} (known: "
                                       f"{', '.join(sorted(lib))})")
        over = _flatten({k: v for k, v in spec.items() if k != "model"})
        materials[label] = _material(label, model, lib, over, key)

    # bodies -------------------------------------------------------------------------------
    bl = s["bodies"]
    if not isinstance(bl, (list, tuple)) or not bl:
        raise _err("bodies", "must be a non-empty list of tables")
    bodies, names = [], set()
    used = {}
    for k, b in enumerate(bl):
        key = f"bodies[{k}]"
        b = _table(b, key)
        shape_b = b.get("shape")
        if not isinstance(shape_b, str) or shape_b not in BODY_KEYS:
            raise _err(f"{key}.shape", f"must be one of {', '.join(BODY_KEYS)}, got {shape_b!r}")
        _keys(b, ("name", "material", "shape", "velocity") + BODY_KEYS[shape_b], key)
        name = b.get("name", f"body{k}")
        if not isinstance(name, str) or not name:
            raise _err(f"{key}.name", f"must be a non-empty string, got {name!r}")
        if name in names:
            raise _err(f"{key}.name", f"duplicate body name {name!r}")
        names.add(name)
        if "material" not in b:
            raise _err(f"{key}.material", "is required")
        mat = b["material"]
        if not isinstance(mat, str):
            raise _err(f"{key}.material", f"must be a name, got {mat!r}")
        if mat not in materials:
            if mat in lib:                       # a library name used directly as a label
                materials[mat] = _material(mat, mat, lib, {}, f"{key}.material")
            else:
                raise _err(f"{key}.material", f"unknown material {mat!r} (scene materials: "
                           f"{', '.join(materials) or 'none'}; library: "
                           f"{', '.join(sorted(lib))})")
        used[mat] = True
        geom = {}
        if shape_b == "rectangle":
            for kk in ("min", "max"):
                if kk not in b:
                    raise _err(f"{key}.{kk}", "is required")
            geom["min"] = _pair(b["min"], f"{key}.min")
            geom["max"] = _pair(b["max"], f"{key}.max")
            if geom["max"][0] <= geom["min"][0] or geom["max"][1] <= geom["min"][1]:
                raise _err(f"{key}.max", "must be above min in x and y")
            box = (*geom["min"], *geom["max"])
        elif shape_b == "circle":
            for kk in ("center", "radius"):
                if kk not in b:
                    raise _err(f"{key}.{kk}", "is required")
            geom["center"] = _pair(b["center"], f"{key}.center")
            geom["radius"] = _num(b["radius"], f"{key}.radius", positive=True)
            cx, cy = geom["center"]
            r = geom["radius"]
            box = (cx - r, cy - r, cx + r, cy + r)
        else:
            if "vertices" not in b:
                raise _err(f"{key}.vertices", "is required")
            vs = b["vertices"]
            if not isinstance(vs, (list, tuple)) or len(vs) < 3:
                raise _err(f"{key}.vertices", "must list at least 3 points [x, y]")
            pts = [_pair(v, f"{key}.vertices[{i}]") for i, v in enumerate(vs)]
            geom["vertices"] = np.array(pts)
            box = (*geom["vertices"].min(axis=0), *geom["vertices"].max(axis=0))
        tol = 1e-9 * max(x1 - x0, y1 - y0)
        if box[0] < x0 - tol or box[1] < y0 - tol or box[2] > grid.x1 + tol or \
                box[3] > grid.y1 + tol:
            raise _err(key, f"extends outside the domain [{x0:g}, {grid.x1:g}] x "
                            f"[{y0:g}, {grid.y1:g}]")
        vel = _pair(b.get("velocity", [0.0, 0.0]), f"{key}.velocity")
        bodies.append(Body(name, mat, shape_b, geom, vel))
    for label in list(materials):
        if label not in used:
            del materials[label]      # listed but unused: not compiled, no parameters

    det = None
    if "detonation" in s:
        d = _table(s["detonation"], "detonation")
        _keys(d, ("point",), "detonation")
        if "point" not in d:
            raise _err("detonation.point", "is required")
        det = _pair(d["point"], "detonation.point")

    # probes -------------------------------------------------------------------------------
    probes = []
    pl = s.get("probes", [])
    if not isinstance(pl, (list, tuple)):
        raise _err("probes", "must be a list of tables {name, point, body, radius}")
    pnames = set()
    for k, p in enumerate(pl):
        key = f"probes[{k}]"
        p = _table(p, key)
        _keys(p, PROBE_KEYS, key)
        if "name" not in p or not isinstance(p["name"], str) or not p["name"]:
            raise _err(f"{key}.name", "is required (a non-empty string)")
        if not PROBE_NAME.fullmatch(p["name"]) or p["name"].startswith("."):
            raise _err(f"{key}.name", f"{p['name']!r} cannot name files: a probe name names "
                                      f"its figures, so it is letters, digits, '_', '.' and "
                                      f"'-' only, not starting with '.'")
        if p["name"] in pnames:
            raise _err(f"{key}.name", f"duplicate probe name {p['name']!r}")
        pnames.add(p["name"])
        if "point" not in p:
            raise _err(f"{key}.point", "is required")
        pt = _pair(p["point"], f"{key}.point")
        body = p.get("body")
        if body is not None and (not isinstance(body, str) or body not in names):
            raise _err(f"{key}.body", f"no body named {body!r} (bodies: {', '.join(names)})")
        radius = None
        if "radius" in p:
            radius = _num(p["radius"], f"{key}.radius", positive=True)
            spacing = dx / ppc
            if radius < MIN_RADIUS_SPACINGS * spacing:
                raise _err(f"{key}.radius", f"{radius:g} m is less than {MIN_RADIUS_SPACINGS:g} "
                           f"particle spacings ({MIN_RADIUS_SPACINGS * spacing:g} m at cell "
                           f"{dx:g} m, {ppc} particles per cell): the average would move with "
                           f"the particle layout; drop radius for the nearest particle")
        probes.append(Probe(p["name"], pt, body, radius))

    snaps = _snapshots(s["snapshots"], dt_out) if "snapshots" in s else None
    materials = apply_conventions(materials, conventions)
    _check_material_constants(materials)

    return Config(grid=grid, ppc=ppc, shape=shape, flip=flip, cfl=cfl, q1=q1, q2=q2,
                  gravity=gravity, end_time=end, output_interval=dt_out, outputs=tuple(outs),
                  dt_min=dt_min, max_steps=max_steps, threads=threads, materials=materials, bodies=bodies,
                  probes=probes, detonation=det, cell_size=cell, resolution=res,
                  extent=extent, extent_margin=margin, snapshots=snaps,
                  conventions=conventions)


def _snapshots(v, dt_out) -> Snapshots:
    """``snapshots = { interval, directory, fields }``: particle VTK files (snapshots.py)."""
    sn = _table(v, "snapshots")
    _keys(sn, SNAPSHOT_KEYS, "snapshots")
    for k in ("interval", "directory"):
        if k not in sn:
            raise _err(f"snapshots.{k}", "is required")
    interval = _num(sn["interval"], "snapshots.interval", positive=True)
    ratio = interval / dt_out
    every = round(ratio)
    if every < 1 or abs(ratio - every) > SNAPSHOT_MULTIPLE_RTOL * every:
        raise _err("snapshots.interval", f"must be a multiple of output_interval = {dt_out:g} s "
                                         f"(the state is sampled at output times only), got "
                                         f"{interval:g} s = {ratio:.6g} x output_interval")
    d = sn["directory"]
    if not isinstance(d, str) or not d.strip():
        raise _err("snapshots.directory", f"must be a non-empty path, got {d!r}")
    directory = os.path.abspath(os.path.expanduser(d))
    fields = _names(sn.get("fields", list(DEFAULT_SNAPSHOT_FIELDS)), "snapshots.fields",
                    SNAPSHOT_FIELDS, "field")
    return Snapshots(interval=every * dt_out, every=int(every), directory=directory,
                     fields=tuple(fields))


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


def _material(label, model, lib, overrides, key):
    module, defaults = lib[model]
    params = dict(module.PARAMETERS)
    params.update(defaults or {})
    for name, v in overrides.items():
        if name not in params:
            raise _err(f"{key}.{name}", f"material {model!r} has no parameter {name!r} "
                                        f"(takes {', '.join(params)})")
        params[name] = _num(v, f"{key}.{name}")
    return Material(label, model, module, params, dict(overrides))


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
    then moves with the material; ties to the lowest index). A probe farther than one cell from every candidate is a
    SceneError (the point is not in that body)."""
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
