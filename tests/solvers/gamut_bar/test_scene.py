"""The typed gamut-bar scene (solvers/gamut_bar/scene.py): every shipped scene parses to what
its keys mean, and a bad key is one line naming file and key."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import pytest

from solvers.gamut_bar import GamutBarSolver
from solvers.gamut_bar.materials import MATERIALS, modulus_of_softness
from solvers.gamut_bar.scene import parse_scene
from uqflow.errors import SceneError, StudyError
from uqflow.study import load_study

ROOT = Path(__file__).resolve().parents[3]
SHIPPED = sorted((ROOT / "studies" / "gamut_bar").glob("*.toml"))


def _scene(study: Path) -> dict:
    return tomllib.loads(study.read_text())["scene"]


def _expected(scene) -> tuple[dict, dict]:
    """(cfg, props) of a valid scene, from the documented defaults and the seed's materials
    (written out here, independently of scene.py)."""
    defaults = {"material": "M1", "grid": "uniform", "loading": "monotonic",
                "local_bonds": 500, "grid_factor": 0.65, "min_spacing_fraction": 0.05,
                "grid_seed": 0, "sigma_stdev": 8.0, "cutoff": 3.0, "curve_points": 400,
                "cycles": 10, "cycle_repeats": 2, "amplitude_range": (1.0, 1.1),
                "initial_force": 0.01, "force_growth": 1.01, "cyclic_increment": 0.01,
                "bisections": 30}
    properties = ("E", "sigma_y", "sigma_f", "eps_f", "n_ro", "K_ro", "rho", "nu", "R",
                  "area", "length")
    cfg = {k: scene.get(k, v) for k, v in defaults.items()}
    cfg["amplitude_range"] = tuple(cfg["amplitude_range"])
    cfg["R_given"] = "R" in scene
    props = dict(MATERIALS[cfg["material"]], area=1.0e-4, length=0.1)
    props.update({k: scene[k] for k in properties if k in scene})
    if "R" not in scene:
        props["R"] = modulus_of_softness(props["E"], props["sigma_f"], props["eps_f"],
                                         props["sigma_y"], props["n_ro"], props["K_ro"])
    return cfg, props


def test_twenty_shipped_scenes():
    assert len(SHIPPED) == 20


@pytest.mark.parametrize("study", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_every_shipped_scene_parses_to_its_documented_meaning(study):
    """(Until the hand-written parser was deleted, this compared it with the typed scene on
    every shipped scene and ~2,000 malformed variants: all alike.)"""
    cfg, props = parse_scene(_scene(study))
    assert (cfg, props) == _expected(_scene(study))   # ==: bit for bit, same keys
    solver = GamutBarSolver.from_scene(_scene(study))
    assert solver.props == props and solver.n == cfg["local_bonds"]


BAD = [  # (scene edit, key the error names, words of its reason)
    ({"local_bonds": 10.0}, "scene.local_bonds", "write 10, not 10.0"),
    ({"local_bonds": 10**6 + 1}, "scene.local_bonds", "less than or equal to 1000000"),
    ({"E": True}, "scene.E", "must be a number, got true"),
    ({"E": "71.6e9"}, "scene.E", "valid number"),
    ({"E": math.nan}, "scene.E", "finite number"),
    ({"sigma_yy": 1.0}, "scene.sigma_yy", "unknown key (did you mean 'sigma_y'?)"),
    ({"eps_y": 0.01}, "scene.eps_y", "is derived"),
    ({"material": "M3"}, "scene.material", "'M1' or 'M2', got 'M3'"),
    ({"amplitude_range": [1.0, -1.0]}, "scene.amplitude_range[1]", "greater than 0"),
    ({"amplitude_range": [1.1, 1.0]}, "scene.amplitude_range", "low must be below high"),
    ({"cyclic_increment": 0.03}, "scene.cyclic_increment", "1/integer"),
    ({"sigma_f": 500e6}, "scene.sigma_f", "below the yield stress"),
    ({"cutoff": 0.2}, "scene.cutoff", "no nonlocal bond"),
    ({"n_ro": 1.0}, "scene.n_ro", "greater than 1"),
]


@pytest.mark.parametrize("edit,key,reason", BAD, ids=[b[1] + "-" + str(i)
                                                      for i, b in enumerate(BAD)])
def test_errors_name_the_file_and_the_key_in_one_line(edit, key, reason, tmp_path):
    """Through load_study: an inline scene's error names the study file, a scene file's the
    scene file; one line ``<file>: scene.<key>: <reason>``."""
    base = {"material": "M1", "local_bonds": 20, "loading": "cyclic", "cycles": 3}
    scene = dict(base, **edit)
    inline = tmp_path / "inline.toml"
    inline.write_text('name = "t"\nsolver = "gamut_bar"\nscene = '
                      + _inline(scene) + '\n[method]\nkind = "nominal"\n')
    scene_file = tmp_path / "bar.toml"
    scene_file.write_text("\n".join(f"{k} = {_toml(v)}" for k, v in scene.items()) + "\n")
    by_file = tmp_path / "by_file.toml"
    by_file.write_text('name = "t"\nsolver = "gamut_bar"\nscene = "bar.toml"\n'
                       '[method]\nkind = "nominal"\n')
    for study, named in ((inline, inline), (by_file, scene_file)):
        with pytest.raises(StudyError) as caught:
            load_study(study)
        err = caught.value
        assert (err.file, err.key) == (str(named), key), str(err)
        assert reason in err.reason and "\n" not in str(err)
        assert str(err).startswith(f"{named}: {key}: ")


def test_a_scene_that_is_no_table():
    with pytest.raises(SceneError) as caught:
        GamutBarSolver.from_scene([1, 2])
    assert caught.value.key == "scene"


def _toml(v) -> str:
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float) and math.isnan(v):
        return "nan"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, list):
        return "[" + ", ".join(map(_toml, v)) + "]"
    return repr(v)


def _inline(scene) -> str:
    return "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in scene.items()) + " }"
