"""The MPM scene parser as it was before the scenes became pydantic declarations (issue 17,
point 5), kept only while both exist: test_scene_models compares the two on every shipped
scene. Deleted with that comparison."""
# flake8: noqa
from __future__ import annotations

import math
import os
from collections.abc import Mapping

import numpy as np

from solvers.mpm.grid import SIDE_KINDS, SIDES, Grid
from solvers.mpm.shapes import KINDS
from solvers.mpm.scene import (BODY_KEYS, CONVENTIONS, DEFAULT_OUTPUTS, DEFAULT_SNAPSHOT_FIELDS,
                               EXTENT_MARGIN_CELLS, MAX_EXTENT_MARGIN,
                               MAX_LATTICE_POINTS, MAX_PADDING, MAX_STEPS, MAX_THREADS,
                               MIN_RADIUS_SPACINGS, PROBE_NAME, PROBE_QUANTITIES,
                               SNAPSHOT_FIELDS,
                               SNAPSHOT_MULTIPLE_RTOL, Body, Config, Material, Probe,
                               Snapshots, _check_material_constants, _library, apply_conventions)
from uqflow.errors import SceneError
from uqflow.scene_checks import (check_keys, integer, is_number, number, number_pair,
                                 scene_error, table)

TOP_KEYS = ("domain", "cell_size", "resolution", "particles_per_cell", "shape", "flip", "cfl",
            "bulk_viscosity", "gravity", "end_time", "output_interval", "outputs", "dt_min",
            "padding", "extent", "materials", "bodies", "detonation", "boundaries", "clamps",
            "probes", "max_steps", "threads", "extent_margin", "snapshots", "conventions")
REQUIRED = ("domain", "cell_size", "bodies", "end_time")
SNAPSHOT_KEYS = ("interval", "directory", "fields")
DEFAULTS = {"resolution": 1.0, "particles_per_cell": 2, "shape": "quadratic", "flip": 1.0,
            "cfl": 0.3, "gravity": [0.0, 0.0], "padding": 3, "extent": "full",
            "max_steps": 5_000_000, "threads": 1, "conventions": "uqflow"}
PROBE_KEYS = ("name", "point", "body", "radius")

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


