"""The typed gamut-bar scene (solvers/gamut_bar/scene.py): every shipped scene parses to the
scene the hand-written parser made, and a bad key is one line naming file and key."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import pytest

from solvers.gamut_bar import GamutBarSolver
from solvers.gamut_bar.scene import parse_scene
from uqflow.errors import SceneError

ROOT = Path(__file__).resolve().parents[3]
SHIPPED = sorted((ROOT / "studies" / "gamut_bar").glob("*.toml"))


def _scene(study: Path) -> dict:
    return tomllib.loads(study.read_text())["scene"]


def _old(scene):
    """(cfg, props) as the hand-written ``from_scene`` made them, or the SceneError's key."""
    try:
        s = GamutBarSolver._from_scene_by_hand(scene)
    except SceneError as exc:
        return exc.key
    return dict(s.cfg, R_given=s._R_given), s.props


def _new(scene):
    try:
        return parse_scene(scene)
    except SceneError as exc:
        return exc.key


def test_twenty_shipped_scenes():
    assert len(SHIPPED) == 20


@pytest.mark.parametrize("study", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_every_shipped_scene_parses_as_before(study):
    old, new = _old(_scene(study)), _new(_scene(study))
    assert not isinstance(old, str)
    assert new == old           # ==: same values, bit for bit, and same keys


def _variants(scene):
    """Each key of ``scene`` and of the defaults turned, one at a time, into a malformed value."""
    keys = list(scene) + ["E", "sigma_f", "eps_f", "n_ro", "R", "nu", "grid_factor",
                          "min_spacing_fraction", "grid_seed", "sigma_stdev", "cutoff",
                          "curve_points", "cycle_repeats", "initial_force", "force_growth",
                          "cyclic_increment", "bisections", "eps_y", "E_typo"]
    bad = [True, "2", math.nan, math.inf, 1e300, -1.0, 0, 1, 2**63 - 1, 10**400, 2.0, 0.5,
           [1.0], {"v": 1}, [1.0, 1.3], [1.1, 1.0],
           0.99, 1e-4, 0.5, 100, 101, 1000, 1001, 10**6 + 1, 2**64 - 1, 2**64]  # bounds
    for key in keys:
        for value in bad:
            yield key, dict(scene, **{key: value})
        if key in scene:
            yield key, {k: v for k, v in scene.items() if k != key}


@pytest.mark.parametrize("study", SHIPPED[:4] + SHIPPED[-2:], ids=lambda p: p.stem)
def test_malformed_scenes_are_refused_or_parsed_as_before(study):
    """Around shipped scenes: both parsers accept (the same scene) or refuse naming the same
    key."""
    compared = 0
    for key, scene in _variants(_scene(study)):
        old, new = _old(scene), _new(scene)
        assert new == old, (key, scene[key] if key in scene else "missing")
        compared += 1
    assert compared > 300
