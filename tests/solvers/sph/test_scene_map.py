"""The map of an SPH scene (solvers/sph/scene_map.py) and its place in every result's report."""

import hashlib
import json

from types import SimpleNamespace

import numpy as np
import pytest
import xarray as xr

from solvers.sph import SPHSolver
from solvers.sph.layouts import Box
from solvers.sph.report import report
from solvers.sph.scene import parse
from solvers.sph.scene_layout import scene_layout
from solvers.sph.scene_map import (INCLUSION, LOAD, MATRIX, PAIRS, PLATE, SUPPORT,
                                   draw_scene_map, pairs_visible)

#: two ellipses in an 80 x 60 m plate, 4 m spacing (336 particles), pulled apart in 2 steps
TWO_ELLIPSES = dict(layout="regular", width=80.0, height=60.0, spacing=4.0,
                    inclusions=[dict(centre=[-18.0, 0.0], semi_axes=[8.0, 6.0]),
                                dict(centre=[18.0, 0.0], semi_axes=[6.0, 8.0], angle_deg=30.0)],
                    matrix=dict(E=2e9, nu=0.35), inclusion=dict(E=70e9, nu=0.22),
                    loading="tension", step=0.1, steps=2)
#: Example 1 of the seed, coarse: one circle, an eigenstrain, the exact edge
ONE_CIRCLE = dict(layout="polar", outer_radius=0.06, spacing=0.006,
                  inclusions=[dict(centre=[0.0, 0.0], semi_axes=[0.02, 0.02])],
                  matrix=dict(E=900.0, nu=0.33), inclusion=dict(E=1000.0, nu=0.28),
                  loading="eigenstrain", eigenstrain=0.01)
MM = 1e3


def _map(scene):
    cfg = parse(scene)
    layout = scene_layout(cfg)
    fig = draw_scene_map(cfg, layout)
    return fig, fig.axes[0], cfg, layout


def _by_gid(ax, gid):
    return [a for a in ax.get_children() if a.get_gid() == gid]


def _legend_texts(fig):
    return [t.get_text() for legend in fig.legends + [ax.get_legend() for ax in fig.axes]
            if legend is not None for t in legend.get_texts()]


def test_the_map_draws_every_particle_by_material_and_every_inclusion():
    fig, ax, cfg, layout = _map(TWO_ELLIPSES)
    inside = layout.phase > 0
    (matrix,), (inclusion,) = _by_gid(ax, MATRIX), _by_gid(ax, INCLUSION)
    np.testing.assert_array_equal(matrix.get_offsets(), layout.x[~inside] * MM)
    np.testing.assert_array_equal(inclusion.get_offsets(), layout.x[inside] * MM)
    assert not np.allclose(matrix.get_facecolor(), inclusion.get_facecolor())
    for k, spec in enumerate(cfg.inclusions):
        (outline,) = _by_gid(ax, f"inclusion {k}")
        assert outline.center == pytest.approx(np.array(spec.centre) * MM, abs=0)
        assert (outline.width, outline.height) == pytest.approx(
            (2 * spec.semi_axes[0] * MM, 2 * spec.semi_axes[1] * MM), abs=0)
        assert outline.angle == pytest.approx(spec.angle_deg, rel=4 * np.finfo(float).eps)
    assert len([a for a in ax.patches if str(a.get_gid()).startswith("inclusion ")]) == 2
    (plate,) = _by_gid(ax, PLATE)
    assert (plate.get_width(), plate.get_height()) == (80.0 * MM, 60.0 * MM)
    texts = _legend_texts(fig)
    assert "matrix: E = 2 GPa, ν = 0.35" in texts
    assert "inclusion: E = 70 GPa, ν = 0.22" in texts
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x [mm]", "y [mm]")


def test_the_map_draws_the_interface_pairs_the_constraints_tie():
    fig, ax, cfg, layout = _map(TWO_ELLIPSES)
    (pairs,) = _by_gid(ax, PAIRS)
    np.testing.assert_array_equal(pairs.get_offsets(), layout.x[layout.pairs[:, 0]] * MM)
    assert "interface pairs, tied by master–slave constraints" in _legend_texts(fig)


def test_the_map_draws_the_pull_on_both_edges_and_the_held_particles():
    fig, ax, cfg, layout = _map(TWO_ELLIPSES)
    arrows = _by_gid(ax, LOAD)
    assert len(arrows) >= 4
    box: Box = layout.domain
    ups = [a for a in arrows if a.xy[1] > a.xyann[1]]
    downs = [a for a in arrows if a.xy[1] < a.xyann[1]]
    assert len(ups) == len(downs) == len(arrows) // 2
    assert all(a.xyann[1] == pytest.approx(box.y1 * MM) for a in ups)
    assert all(a.xyann[1] == pytest.approx(box.y0 * MM) for a in downs)
    (held,) = _by_gid(ax, SUPPORT)
    # the particles loading.tension_boundary_values holds in x: middle of top and bottom
    assert sorted(held.get_ydata()) == pytest.approx([box.y0 * MM, box.y1 * MM])
    assert np.allclose(held.get_xdata(), 0.0)
    assert any("pulled apart, 100 mm per step, 2 steps" in t for t in _legend_texts(fig))


def test_the_map_of_an_eigenstrain_scene_marks_the_inclusion_and_the_prescribed_edge():
    fig, ax, cfg, layout = _map(ONE_CIRCLE)
    (label,) = _by_gid(ax, LOAD)
    assert label.get_text().startswith("eigenstrain 0.01")
    assert label.xy == pytest.approx((0.0, 0.0))
    (edge,) = _by_gid(ax, SUPPORT)
    np.testing.assert_array_equal(np.c_[edge.get_xdata(), edge.get_ydata()],
                                  layout.x[layout.boundary] * MM)
    (disc,) = _by_gid(ax, PLATE)
    assert disc.radius == pytest.approx(60.0)
    assert "edge displacement prescribed: the exact (Eshelby) solution" in _legend_texts(fig)


def _tree(attrs, runs=None):
    groups = {"/": xr.Dataset(attrs={"study_name": "t", "solver": "sph", **attrs})}
    if runs is not None:
        groups["/runs"] = runs
    return xr.DataTree.from_dict(groups)


def _study_text(scene: dict) -> str:
    lines = [f"{k} = {json.dumps(v)}" for k, v in scene.items() if not isinstance(v, (dict, list))]
    lines += [f"{k} = {{ E = {v['E']!r}, nu = {v['nu']!r} }}" for k, v in scene.items()
              if isinstance(v, dict)]
    inclusions = ", ".join("{ centre = %s, semi_axes = %s }" % (i["centre"], i["semi_axes"])
                           for i in scene["inclusions"])
    lines.append(f"inclusions = [{inclusions}]")
    return 'name = "t"\nsolver = "sph"\n[scene]\n' + "\n".join(lines) + \
        '\n[method]\nkind = "nominal"\n'


def test_every_sph_result_gets_a_scene_map_through_the_solver_hook(tmp_path):
    # an eigenstrain result has no moduli: the map is all the solver adds
    text, paths = SPHSolver.report([_tree({"study": _study_text(ONE_CIRCLE)})], tmp_path)
    assert paths == [tmp_path / "scene_map.png"] and paths[0].stat().st_size > 0
    assert "scene map of the study's inline scene table" in text


def test_a_scene_file_is_mapped_while_it_holds_what_the_study_read(tmp_path):
    scene_file = tmp_path / "scene.toml"
    scene_file.write_text(_study_text(ONE_CIRCLE).split("[scene]\n")[1].split("[method]")[0])
    sha = hashlib.sha256(scene_file.read_text().encode()).hexdigest()
    tree = _tree({"study": 'name = "t"\nscene = "scene.toml"\n',
                  "study_read_files": json.dumps({"scene": [str(scene_file), sha]})})
    text, paths = report([tree], tmp_path / "figures")
    assert [p.name for p in paths] == ["scene_map.png"]
    scene_file.write_text(scene_file.read_text().replace("0.01", "0.02"))
    text, paths = report([tree], tmp_path / "figures")
    assert paths == [] and "no scene map: the scene file" in text and "changed" in text


def test_no_map_is_drawn_without_figures(tmp_path):
    text, paths = report([_tree({"study": _study_text(ONE_CIRCLE)})], tmp_path, figures=False)
    assert paths == [] and not tmp_path.joinpath("scene_map.png").exists()


def test_the_scene_map_names_are_one_per_result(tmp_path):
    tree = _tree({"study": _study_text(ONE_CIRCLE)})
    _, paths = report([tree, tree], tmp_path)
    assert [p.name for p in paths] == ["scene_map_0.png", "scene_map_1.png"]


def test_the_map_draws_the_layout_the_solver_runs():
    cfg = parse(TWO_ELLIPSES)
    assert np.array_equal(scene_layout(cfg).x, SPHSolver.from_scene(TWO_ELLIPSES).layout.x)


def test_the_interface_pairs_are_shown_up_to_200_spacings_across():
    def plate(spacings):
        return SimpleNamespace(x=np.array([[0.0, 0.0], [spacings * 1e-6, 0.5e-6]]), spacing=1e-6)
    assert pairs_visible(plate(200)) and not pairs_visible(plate(201))
