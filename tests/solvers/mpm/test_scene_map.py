"""The scene map (solvers/mpm/scene_map.py) and how the MPM report finds a result's scene
(issue 17, point 2): every body filled in its material's colour, materials named in words,
every probe a marker labelled with its name and position in mm, the grid, axes in mm."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest
from matplotlib.colors import to_rgba

from solvers.mpm import report as mpm_report
from solvers.mpm.scene import parse
from solvers.mpm.scene_map import draw_scene_map, material_words
from uqflow.report import scene_ran

from .test_report import trees, write

CHARGE = {"name": "charge", "material": "tnt", "shape": "rectangle", "min": [-0.01, 0.0],
          "max": [0.01, 0.01]}
PLATE = {"name": "plate", "material": "steel", "shape": "rectangle", "min": [0.01, 0.0],
         "max": [0.02, 0.05]}
DISK = {"name": "disk", "material": "tnt", "shape": "circle", "center": [-0.03, 0.03],
        "radius": 0.005}
WEDGE = {"name": "wedge", "material": "steel", "shape": "polygon",
         "vertices": [[0.03, 0.0], [0.04, 0.0], [0.04, 0.02]]}
WATER = {"name": "pool", "material": "water", "shape": "rectangle", "min": [-0.05, 0.0],
         "max": [0.05, 0.05]}


def tiny_scene(probes=None) -> dict:
    """A contact explosion in miniature: every shape, three materials, a clamp, probes."""
    return {"domain": {"x": [-0.05, 0.05], "y": [0.0, 0.05]}, "cell_size": 0.005,
            "end_time": 1e-6, "boundaries": {"bottom": "symmetry"},
            "detonation": {"point": [0.0, 0.0]},
            "clamps": [{"min": [0.01, 0.045], "max": [0.02, 0.05]}],
            "materials": {"steel": {"model": "steel_4340"}, "tnt": {"model": "tnt"},
                          "water": {"model": "water"}},
            "bodies": [CHARGE, PLATE, DISK, WEDGE, WATER],
            "probes": probes if probes is not None else [
                {"name": "H", "point": [0.0125, 0.0], "body": "plate"},
                {"name": "far", "point": [-0.03, 0.03]}]}


def _texts(fig) -> list[str]:
    out = [t.get_text() for t in fig.texts]
    for ax in fig.axes:
        out += [t.get_text() for t in ax.texts]
    for legend in fig.legends:
        out += [t.get_text() for t in legend.get_texts()]
    return out


def _by_gid(ax, prefix):
    return {a.get_gid().split(":", 1)[1]: a for a in ax.get_children()
            if isinstance(a.get_gid(), str) and a.get_gid().startswith(prefix)}


def test_every_body_is_filled_in_its_materials_colour():
    cfg = parse(tiny_scene())
    fig = draw_scene_map(cfg)
    ax = fig.axes[0]
    bodies = _by_gid(ax, "body:")
    assert set(bodies) == {"charge", "plate", "disk", "wedge", "pool"}
    # one colour per material, the same for every body of it, and told apart
    colour = {b.name: bodies[b.name].get_facecolor() for b in cfg.bodies}
    assert colour["charge"] == colour["disk"] and colour["plate"] == colour["wedge"]
    assert len({colour["charge"], colour["plate"], colour["pool"]}) == 3
    # the first body owns what it shares with a later one: it is drawn above it
    assert bodies["charge"].get_zorder() > bodies["pool"].get_zorder()
    # the legend's swatch of each material is its bodies' colour, in words
    legend = fig.legends[0]
    swatches = {t.get_text(): h.get_facecolor() for t, h in
                zip(legend.get_texts(), legend.legend_handles) if hasattr(h, "get_facecolor")}
    assert swatches["TNT: charge, disk"] == colour["charge"]
    assert swatches["AISI 4340 steel: plate, wedge"] == colour["plate"]
    assert swatches["water: pool"] == colour["pool"]


def test_the_geometry_is_drawn_in_mm():
    cfg = parse(tiny_scene())
    ax = draw_scene_map(cfg).axes[0]
    bodies = _by_gid(ax, "body:")
    assert bodies["plate"].get_xy() == pytest.approx((10.0, 0.0))
    assert (bodies["plate"].get_width(), bodies["plate"].get_height()) == \
        pytest.approx((10.0, 50.0))
    assert bodies["disk"].get_center() == pytest.approx((-30.0, 30.0))
    assert bodies["disk"].get_radius() == pytest.approx(5.0)
    assert np.allclose(bodies["wedge"].get_xy()[:3], [[30, 0], [40, 0], [40, 20]])
    grid = next(a for a in ax.patches if a.get_gid() == "grid")
    assert grid.get_xy() == pytest.approx((-50.0, 0.0))
    assert (grid.get_width(), grid.get_height()) == pytest.approx((100.0, 50.0))
    assert ax.get_xlabel() == "x [mm]" and ax.get_ylabel() == "y [mm]"
    assert any(a.get_gid() == "clamp" for a in ax.patches)
    assert "bottom: symmetry" in _texts(ax.figure)


def test_every_probe_is_a_marker_labelled_with_its_name_and_position_in_mm():
    cfg = parse(tiny_scene())
    fig = draw_scene_map(cfg)
    # the probes are 43 mm apart on a 100 mm scene: one panel, labelled there
    assert len(fig.axes) == 1
    markers = _by_gid(fig.axes[0], "probe:")
    assert set(markers) == {"H", "far"}
    assert markers["H"].get_xydata().tolist() == [[12.5, 0.0]]
    assert "H (x = 12.5, y = 0 mm)" in _texts(fig)
    assert "far (x = -30, y = 30 mm)" in _texts(fig)


def test_close_probes_get_a_panel_of_their_own_with_labels_apart():
    probes = [{"name": n, "point": [0.011 + 0.002 * k, 0.0], "body": "plate"}
              for k, n in enumerate("HGKL")]
    scene = tiny_scene(probes)
    scene["cell_size"] = 0.001           # the panel's margin is at least 4 cells
    fig = draw_scene_map(parse(scene))
    assert len(fig.axes) == 2
    zoom = fig.axes[1]
    labels = _by_gid(zoom, "probe-label:")
    assert set(labels) == set("HGKL")
    assert labels["G"].get_text() == "G (x = 13, y = 0 mm)"
    heights = [labels[n].xyann[1] for n in "HGKL"]
    assert len(set(heights)) == 4                      # side by side: one height each
    x0, x1 = zoom.get_xlim()
    assert x0 >= -50.0 and x1 - x0 < 0.5 * 100.0       # around the probes, inside the grid


def test_material_words_fall_back_to_the_library_name():
    scene = tiny_scene()
    scene["materials"]["block"] = {"model": "elastic"}
    scene["bodies"] = [dict(WATER, material="block", name="block")]
    scene["probes"] = []
    scene.pop("detonation")
    cfg = parse(scene)
    assert material_words(cfg, "block") == "elastic solid: block"
    fig = draw_scene_map(cfg)
    assert "probe" not in _texts(fig) and "detonation point" not in _texts(fig)


# ------------------------------------------------------------------------- the report's map

def _scene_file(tmp_path, scene_text):
    path = tmp_path / "scene.toml"
    path.write_text(scene_text)
    return path, hashlib.sha256(scene_text.encode()).hexdigest()


TOML = """domain = { x = [-0.05, 0.05], y = [0.0, 0.05] }
cell_size = 0.005
end_time = 1e-6
detonation = { point = [0.0, 0.0] }
[materials.steel]
model = "steel_4340"
[[bodies]]
name = "charge"
material = "tnt"
shape = "rectangle"
min = [-0.01, 0.0]
max = [0.01, 0.01]
[[bodies]]
name = "plate"
material = "steel"
shape = "rectangle"
min = [0.01, 0.0]
max = [0.02, 0.05]
[[probes]]
name = "H"
point = [0.0125, 0.0]
"""


def test_the_report_draws_the_scene_file_the_study_read(tmp_path):
    path, sha = _scene_file(tmp_path, TOML)
    mc = write(tmp_path / "mc.nc", method="monte-carlo", stderr=1e7, scene=(str(path), sha))
    text, pngs = mpm_report.report(trees(mc), tmp_path / "figs")
    assert pngs[0] == tmp_path / "figs" / "scene_map.png" and pngs[0].stat().st_size > 0
    assert "no scene map" not in text
    _, nothing = mpm_report.report(trees(mc), tmp_path / "none", figures=False)
    assert nothing == [] and not (tmp_path / "none").exists()


def test_a_scene_file_changed_after_the_run_is_not_drawn_and_the_note_says_why(tmp_path):
    path, sha = _scene_file(tmp_path, TOML)
    mc = write(tmp_path / "mc.nc", method="monte-carlo", stderr=1e7, scene=(str(path), sha))
    path.write_text(TOML.replace("0.0125", "0.013"))
    text, pngs = mpm_report.report(trees(mc), tmp_path / "figs")
    assert "scene_map.png" not in [p.name for p in pngs]
    assert f"note: mc.nc: no scene map: the scene file {path} changed after the run " \
           f"(sha256 differs)" in text


def test_an_inline_scene_and_the_command_lines_overrides_are_what_is_drawn(tmp_path):
    import tomllib

    scene = tomllib.loads(TOML)
    study = 'name = "s"\nsolver = "mpm"\nscene = ' + json.dumps(scene) + "\n"
    study = study.replace('": ', '" = ')      # JSON objects as TOML inline tables
    assert tomllib.loads(study)["scene"] == scene
    attrs = {"study": study, "study_overrides": "scene.resolution = 0.5\n"}
    drawn, where = scene_ran(attrs)
    assert where == "the study's inline scene table"
    assert drawn["resolution"] == 0.5 and drawn["bodies"] == scene["bodies"]
    assert parse(drawn).grid.dx == pytest.approx(0.01)


def test_the_figure_colours_are_the_swatches_of_the_legend():
    # the legend would lie if it coloured materials in another order than the bodies
    cfg = parse(tiny_scene())
    fig = draw_scene_map(cfg)
    colours = {to_rgba(h.get_facecolor()) for h in fig.legends[0].legend_handles[:3]}
    bodies = {to_rgba(p.get_facecolor()) for p in _by_gid(fig.axes[0], "body:").values()}
    assert colours == bodies


def test_the_docs_state_the_probe_panels_rule():
    from pathlib import Path

    from solvers.mpm import scene_map

    doc = " ".join((Path(__file__).resolve().parents[3] / "docs" / "mpm_report.md").read_text(
        encoding="utf-8").split())
    assert "smaller than a fifth of the domain in both directions" in doc
    assert "(margin: half their spread, at least 4 cells)" in doc
    assert (scene_map.ZOOM_BELOW, scene_map.ZOOM_MARGIN, scene_map.ZOOM_MIN_CELLS) == \
        (0.2, 0.5, 4)


def test_uqflow_run_writes_the_scene_map_with_the_result(tmp_path):
    from uqflow.cli import main

    (tmp_path / "scene.toml").write_text(TOML)
    (tmp_path / "study.toml").write_text(
        'name = "tiny"\nsolver = "mpm"\nscene = "scene.toml"\noutputs = ["pressure"]\n'
        '[method]\nkind = "nominal"\n[execution]\nworkers = 0\n'
        '[output]\npath = "tiny.nc"\n')
    assert main(["run", str(tmp_path / "study.toml"), "--quiet"]) == 0
    drawn = tmp_path / "tiny_figures" / "scene_map.png"
    assert drawn.is_file() and drawn.stat().st_size > 0
