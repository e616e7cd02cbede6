"""The MPM scene as pydantic declarations (issue 17, point 5): every shipped MPM scene parses
to the same Config as before, bit for bit, and a bad value is one SceneError naming the key.

``scene_configs.json`` holds, per shipped scene (and a scene with every key), the SHA-256 of
its Config in ``canonical`` form as the hand-written parser built it before the declarations
replaced it (both were compared here, then the old one was deleted: git log of this file)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import tomllib
import types
from pathlib import Path

import numpy as np
import pytest

from solvers.mpm.scene import SceneSpec, parse, validate
from uqflow.errors import SceneError
from uqflow.levels import scene_with

from ._common import set_at

REPO = Path(__file__).resolve().parents[3]
STUDIES = REPO / "studies"


def _mpm_scenes() -> list[tuple[str, dict]]:
    """(id, scene table) of every scene a shipped study runs with solver mpm, at each of its
    levels, and of every scene file no study reads (the verification scenes)."""
    out, read = {}, set()
    for study in sorted(STUDIES.rglob("*.toml")):
        if study.parent.name == "scenes":
            continue
        doc = tomllib.loads(study.read_text())
        scene = doc.get("scene")
        if isinstance(scene, str):
            path = (study.parent / scene).resolve()
            read.add(path)
            name, scene = path.name, tomllib.loads(path.read_text())
        else:
            name = f"{study.relative_to(STUDIES)}[inline]"
        if doc.get("solver") != "mpm" or not isinstance(scene, dict):
            continue
        out[name] = scene
        levels = doc.get("levels")
        for value in (levels or {}).get("values", []):
            out[f"{name}[{levels['key']}={value}]"] = scene_with(scene, levels["key"], value)
    for path in sorted((STUDIES / "scenes").glob("*.toml")):
        if path.resolve() not in read:
            out[path.name] = tomllib.loads(path.read_text())
    return sorted(out.items())


SHIPPED = _mpm_scenes()
#: {scene id: SHA-256 of repr(canonical(Config))} as the old parser built them
RECORDED = json.loads((Path(__file__).with_name("scene_configs.json")).read_text())


def canonical(value):
    """A comparable form of a Config, bit for bit: floats by their hex, arrays by dtype,
    shape and bytes, modules by name."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return (type(value).__name__,
                {f.name: canonical(getattr(value, f.name)) for f in dataclasses.fields(value)})
    if isinstance(value, types.ModuleType):
        return ("module", value.__name__)
    if isinstance(value, np.ndarray):
        return ("array", str(value.dtype), value.shape, value.tobytes())
    if isinstance(value, dict):
        return ("dict", [(k, canonical(v)) for k, v in value.items()])    # order matters
    if isinstance(value, (list, tuple)):
        return (type(value).__name__, [canonical(v) for v in value])
    if isinstance(value, float):
        return ("float", value.hex())
    return (type(value).__name__, value)


def every_key_scene() -> dict:
    """A tiny scene with what no shipped scene has: a polygon, clamps, snapshots, a library
    material named directly, an unused scene material, a nested override table, default body
    names, every optional key."""
    return {
        "domain": {"x": [0.0, 0.1], "y": [-0.02, 0.08]}, "cell_size": 0.01, "resolution": 1.0,
        "particles_per_cell": 3, "shape": "gimp", "flip": 0.95, "cfl": 0.25,
        "bulk_viscosity": {"Q1": 1.0}, "gravity": [0.0, -9.81], "end_time": 2e-5,
        "output_interval": 5e-6, "dt_min": 1e-12, "max_steps": 1000, "threads": 0,
        "padding": 4, "extent": "auto", "extent_margin": 2, "outputs": ["pressure", "S11"],
        "conventions": "seed",
        "boundaries": {"left": "fixed", "bottom": "symmetry"},
        "clamps": [{"min": [0.0, 0.0], "max": [0.01, 0.01]}],
        "materials": {"yoke": {"model": "steel_4340", "jc": {"A": 8.0e8}, "rho0": 7850},
                      "unused": {"model": "water"}},
        "bodies": [{"material": "yoke", "shape": "polygon",
                    "vertices": [[0.0, 0.0], [0.05, 0.0], [0.05, 0.02], [0.0, 0.03]]},
                   {"material": "water", "shape": "circle", "center": [0.07, 0.03],
                    "radius": 0.02, "velocity": [1.0, 0]},
                   {"name": "lid", "material": "yoke", "shape": "rectangle",
                    "min": [0.0, 0.05], "max": [0.1, 0.06]}],
        "detonation": {"point": [0.07, 0.03]},
        "probes": [{"name": "P.1", "point": [0.02, 0.01]},
                   {"name": "w", "point": [0.07, 0.03], "body": "body1", "radius": 0.005}],
        "snapshots": {"interval": 1e-5, "directory": "/nonexistent/vtk",
                      "fields": ["pressure", "body"]},
    }


def test_every_kind_of_shipped_scene_is_covered():
    names = [n for n, _ in SHIPPED]
    assert len(SHIPPED) >= 15 and any("resolution=0.25" in n for n in names)
    shapes = {b["shape"] for _, s in SHIPPED for b in s["bodies"]}
    assert shapes >= {"rectangle", "circle"}


def digest(cfg) -> str:
    return hashlib.sha256(repr(canonical(cfg)).encode()).hexdigest()


def test_a_scene_with_every_key_parses_as_before():
    assert digest(parse(every_key_scene())) == RECORDED["every-key scene"]


@pytest.mark.parametrize("name, scene", SHIPPED, ids=[n for n, _ in SHIPPED])
def test_shipped_scene_parses_to_the_same_config_as_the_old_parser(name, scene):
    assert digest(parse(scene)) == RECORDED[name]


def test_every_shipped_scene_has_its_record():
    assert sorted(RECORDED) == sorted([n for n, _ in SHIPPED] + ["every-key scene"])


def test_the_comparison_sees_a_one_ulp_change():
    name, scene = SHIPPED[0]
    cfg = parse(scene)
    other = dataclasses.replace(cfg, cfl=float(np.nextafter(cfg.cfl, 1.0)))
    assert digest(other) != digest(cfg)
    cfg = parse(every_key_scene())
    reordered = dataclasses.replace(cfg, materials=dict(reversed(cfg.materials.items())))
    assert digest(reordered) != digest(cfg)


# ------------------------------------------------------------------------------ errors

def _tiny() -> dict:
    return {"domain": {"x": [0.0, 0.1], "y": [0.0, 0.1]}, "cell_size": 0.01,
            "end_time": 1e-5,
            "materials": {"m": {"model": "elastic", "rho0": 1000.0, "E": 1e6, "nu": 0.3}},
            "bodies": [{"name": "block", "material": "m", "shape": "rectangle",
                        "min": [0.02, 0.02], "max": [0.08, 0.08]}],
            "probes": [{"name": "c", "point": [0.05, 0.05], "body": "block"}]}


def _with(path, value):
    return set_at(_tiny(), path, value)


BAD = [
    # (where, value, key named, words of the reason)
    (("cell_size",), True, "scene.cell_size", "finite number"),
    (("particles_per_cell",), "2", "scene.particles_per_cell", "integer"),
    (("particles_per_cell",), 2.0, "scene.particles_per_cell", "integer"),
    (("domain", "y"), [0.1], "scene.domain.y", "pair"),
    (("domain", "colour"), 1, "scene.domain.colour", "unknown key"),
    (("bulk_viscosity",), {"Q1": -1.0}, "scene.bulk_viscosity.Q1", ">= 0"),
    (("bodies", 0, "vertices"), [[0, 0], [1, 0], [0, 1]], "scene.bodies[0].vertices",
     "a rectangle takes"),
    (("bodies", 0, "max"), KeyError, "scene.bodies[0].max", "required"),
    (("bodies", 0, "name"), "", "scene.bodies[0].name", "non-empty"),
    (("bodies",), [{"name": "p", "material": "m", "shape": "polygon",
                    "vertices": [[0.0, 0.0], [0.05, "x"], [0.0, 0.05]]}],
     "scene.bodies[0].vertices[1]", "pair"),
    (("bodies",), [{"name": "a", "material": "m", "shape": "circle", "center": [0.05, 0.05],
                    "radius": 0.01}] * 2, "scene.bodies[1].name", "duplicate"),
    (("materials", "m", "jc"), {"A": 1.0}, "scene.materials.m.jc.A", "no parameter"),
    (("materials", "m", "rho0"), [1.0], "scene.materials.m.rho0", "finite number"),
    (("materials", "2m"), {"model": "elastic"}, "scene.materials.2m", "a name"),
    (("materials", "m", "model"), KeyError, "scene.materials.m.model", "required"),
    (("probes", 0, "name"), "../etc", "scene.probes[0].name", "cannot name files"),
    (("probes", 0, "radius"), 0.001, "scene.probes[0].radius", "particle spacings"),
    (("probes", 0, "body"), 3, "scene.probes[0].body", "body name"),
    (("conventions",), "SEED", "scene.conventions", "'uqflow', 'seed'"),
    (("resolution",), 1000.0, "scene.resolution", "lattice points"),
    (("snapshots",), {"interval": 1.5e-7, "directory": "x"}, "scene.snapshots.interval",
     "multiple of output_interval"),
    (("clamps",), [{"min": [0.05, 0.05], "max": [0.0, 0.0]}], "scene.clamps[0].max",
     "below min"),
]


@pytest.mark.parametrize("path, value, key, says", BAD,
                         ids=[f"{'.'.join(map(str, p))}" for p, *_ in BAD])
def test_a_bad_value_is_one_line_naming_its_key(path, value, key, says):
    with pytest.raises(SceneError) as err:
        parse(_with(path, value))
    assert err.value.key == key, str(err.value)
    assert says in err.value.reason and "\n" not in str(err.value), str(err.value)


def test_the_tiny_scene_itself_is_valid():
    # what makes each BAD case fail is its change, not the scene it changes
    assert isinstance(validate(_tiny()), SceneSpec)
    assert [b.name for b in parse(_tiny()).bodies] == ["block"]


def test_a_scene_file_error_names_the_scene_file_and_key(tmp_path):
    from uqflow.study import load_study

    (tmp_path / "scene.toml").write_text(
        'domain = { x = [0.0, 0.1], y = [0.0, 0.1] }\ncell_size = 0.01\nend_time = 1e-5\n'
        'cfl = "fast"\n[[bodies]]\nmaterial = "water"\nshape = "circle"\n'
        'center = [0.05, 0.05]\nradius = 0.02\n')
    (tmp_path / "study.toml").write_text(
        'name = "s"\nsolver = "mpm"\nscene = "scene.toml"\n[method]\nkind = "nominal"\n')
    with pytest.raises(SceneError) as err:
        load_study(tmp_path / "study.toml")
    assert err.value.file == str(tmp_path / "scene.toml")
    assert err.value.key == "scene.cfl" and "finite number" in err.value.reason


# ------------------------------------------------------------------------------ the docs

DOC = REPO / "docs" / "mpm_scenes.md"


def _schema_rows() -> list[list[str]]:
    text = DOC.read_text(encoding="utf-8")
    part = text.split("## The scene file, declared", 1)[1].split("\n## ", 1)[0]
    return [[c.strip() for c in line.strip("|").split("|")] for line in part.splitlines()
            if line.startswith("| ") and not line.startswith("| table")]


def test_the_docs_list_every_top_level_key_with_its_default():
    rows = {r[1].strip("`"): r for r in _schema_rows() if r[0] == "top"}
    assert sorted(rows) == sorted(SceneSpec.model_fields)
    for key, (_, _, _, default) in rows.items():
        field = SceneSpec.model_fields[key]
        if default == "required":
            assert field.is_required(), key
        elif default.startswith("`") and key not in ("bulk_viscosity",):
            value = tomllib.loads(f"v = {default.strip('`')}")["v"]
            written = field.default
            assert (list(written) if isinstance(written, tuple) else written) == value, key
    spec = validate(_tiny())
    assert (spec.bulk_viscosity.Q1, spec.bulk_viscosity.Q2) == (1.5, 0.06)
    assert spec.sample_interval == spec.end_time / 100


@pytest.mark.parametrize("change, line", [
    ((("cfl",), "fast"), "scene.cfl: must be a finite number, got 'fast'"),
    ((("bodies",), [{"name": "p", "material": "m", "shape": "polygon",
                     "vertices": [[0.0, 0.0], [0.05, "x"], [0.0, 0.05]]}]),
     "scene.bodies[0].vertices[1]: must be a pair of finite numbers [a, b], got [0.05, 'x']"),
    ((("materials", "m", "jc"), {"A": 1.0}),
     "scene.materials.m.jc.A: material 'elastic' has no parameter 'jc.A' (takes rho0, E, nu)"),
    ((("domain", "colour"), 1), "scene.domain.colour: unknown key (known: x, y)"),
])
def test_the_docs_error_examples_are_the_errors(change, line):
    assert f"{line}`" in DOC.read_text(encoding="utf-8").replace("\n", " ")
    with pytest.raises(SceneError) as err:
        parse(_with(*change))
    assert str(err.value) == line
