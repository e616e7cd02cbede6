"""A map of an SPH scene for the engineer who reads its results (docs/sph.md § 10, the scene
map): the plate, every particle coloured by its material with a legend naming the materials
and their moduli in words, the outline of every inclusion, the interface pairs the constraints
tie together (where the particle spacing leaves them visible), the loading as arrows and the
supports as markers; axes in mm.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from solvers.sph.layouts import Box, Layout
from solvers.sph.scene import Config
from uqflow.report import colors, display_units, figure_path, new_figure, save_figure

MM = 1e3                         # metres to millimetres
FILE_NAME = "scene_map"
#: interface pairs get markers of their own when the plate is at most this many particle
#: spacings across; beyond, ~4 markers a millimetre of print merge into the inclusion outline
PAIRS_VISIBLE_UP_TO = 200
#: arrows along each loaded edge
LOAD_ARROWS = 5
#: the constraint methods in words (the legend of the interface pairs)
CONSTRAINT_WORDS = {
    "master-slave": "master–slave constraints",
    "master-slave-cutoff": "master–slave constraints, small relation weights cut off",
    "master-slave-local": "master–slave constraints, no slave in another slave's relation",
    "penalty": "penalty springs",
}
#: gids of the artists (the tests find them by these)
MATRIX, INCLUSION, PLATE, PAIRS, LOAD, SUPPORT = ("matrix particles", "inclusion particles",
                                                  "plate", "interface pairs", "load", "support")


def material_words(phase: str, E: float, nu: float) -> str:
    """'inclusion: E = 150 MPa, ν = 0.3'."""
    scale, units = display_units([E], "Pa")
    return f"{phase}: E = {E * scale:.4g} {units}, ν = {nu:.3g}"


def pairs_visible(layout: Layout) -> bool:
    """Whether the interface pairs can be told apart at the map's scale."""
    xy = np.asarray(layout.x, dtype=float)
    across = float(np.ptp(xy, axis=0).max()) / layout.spacing
    return across <= PAIRS_VISIBLE_UP_TO


def _marker_area(layout: Layout, axes_points: float = 330.0) -> float:
    """Scatter marker area (points²) that leaves neighbouring particles just apart."""
    across = float(np.ptp(np.asarray(layout.x, dtype=float), axis=0).max()) / layout.spacing
    diameter = 0.75 * axes_points / max(across, 1.0)
    return float(np.clip(diameter, 0.5, 9.0) ** 2)


def _domain_patch(layout: Layout):
    from matplotlib.patches import Circle, Rectangle

    d = layout.domain
    if isinstance(d, Box):
        return Rectangle((d.x0 * MM, d.y0 * MM), (d.x1 - d.x0) * MM, (d.y1 - d.y0) * MM,
                         fill=False, lw=1.2, color="0.2", gid=PLATE, zorder=3)
    return Circle((d.cx * MM, d.cy * MM), d.radius * MM, fill=False, lw=1.2, color="0.2",
                  gid=PLATE, zorder=3)


def _inclusion_outlines(ax, layout: Layout) -> None:
    from matplotlib.patches import Ellipse as EllipsePatch

    for k, e in enumerate(layout.inclusions):
        ax.add_patch(EllipsePatch((e.cx * MM, e.cy * MM), 2 * e.a * MM, 2 * e.b * MM,
                                  angle=math.degrees(e.angle), fill=False, lw=0.8,
                                  color="0.15", gid=f"inclusion {k}", zorder=4))


def _tension(ax, cfg: Config, layout: Layout) -> list:
    """Arrows pulling the top edge up and the bottom edge down; a triangle at the particle of
    each edge whose u_x is held (solvers/sph/loading.py)."""
    from matplotlib.lines import Line2D

    xy = np.asarray(layout.x, dtype=float) * MM
    boundary = np.asarray(layout.boundary)
    normal = np.asarray(layout.boundary_normal, dtype=float)
    x0, x1 = xy[:, 0].min(), xy[:, 0].max()
    y0, y1 = xy[:, 1].min(), xy[:, 1].max()
    length = 0.12 * (y1 - y0)
    for x in np.linspace(x0, x1, LOAD_ARROWS + 2)[1:-1]:
        for edge_y, sign in ((y1, 1.0), (y0, -1.0)):
            ax.annotate("", xy=(x, edge_y + sign * length), xytext=(x, edge_y),
                        arrowprops=dict(arrowstyle="-|>", color="C3", lw=1.5),
                        annotation_clip=False, gid=LOAD)
    held = []
    middle = 0.5 * (x0 + x1)
    for edge in (normal[:, 1] > 0.5, normal[:, 1] < -0.5):
        idx = boundary[edge]
        held.append(idx[np.argmin(np.abs(xy[idx, 0] - middle))])
    ax.plot(xy[held, 0], xy[held, 1], "^", color="k", ms=8, gid=SUPPORT, zorder=6,
            clip_on=False)
    step_scale, step_units = display_units([cfg.step], "m")
    strain = 2.0 * cfg.step * cfg.steps / cfg.height
    return [Line2D([], [], color="C3", marker=r"$\uparrow$", ls="", ms=10,
                   label=f"top and bottom edges pulled apart, {cfg.step * step_scale:.3g} "
                         f"{step_units} per step, {cfg.steps} steps (strain up to "
                         f"{100 * strain:.3g} %)"),
            Line2D([], [], color="k", marker="^", ls="",
                   label="u_x held: the middle particle of the top and of the bottom edge")]


def _eigenstrain(ax, cfg: Config, layout: Layout) -> list:
    """The inclusions' eigenstrain as a label pointing at them; the edge's prescribed
    displacement as markers on every edge particle."""
    from matplotlib.lines import Line2D

    xy = np.asarray(layout.x, dtype=float) * MM
    edge = xy[np.asarray(layout.boundary)]
    words = {"in_plane": "in-plane", "dilatation_3d": "dilatation in 3-D"}[cfg.eigenstrain_mode]
    reach = 0.5 * float(np.ptp(xy[:, 0]))
    for e in layout.inclusions:
        ax.annotate(f"eigenstrain {cfg.eigenstrain:.3g}\n({words})",
                    xy=(e.cx * MM, e.cy * MM), xytext=(e.cx * MM + reach, e.cy * MM + reach),
                    ha="left", va="bottom", color="C3", fontsize="small", gid=LOAD, zorder=7,
                    arrowprops=dict(arrowstyle="-|>", color="C3", lw=1.2),
                    bbox=dict(boxstyle="round", fc="white", ec="C3", alpha=0.9),
                    annotation_clip=False)
    ax.plot(edge[:, 0], edge[:, 1], "s", color="k", ms=3, gid=SUPPORT, zorder=6)
    held = ("edge displacement prescribed: the exact (Eshelby) solution" if cfg.edge == "exact"
            else "edge held fixed (u = 0)")
    return [Line2D([], [], color="C3", marker="$ε$", ls="",
                   label=f"eigenstrain {cfg.eigenstrain:.3g} in the inclusion ({words})"),
            Line2D([], [], color="k", marker="s", ls="", ms=4, label=held)]


def draw_scene_map(cfg: Config, layout: Layout, title: str = ""):
    """The map of ``cfg`` with the particles of ``layout`` (a Figure, not yet saved)."""
    fig, ax = new_figure(7.0, 8.0)
    xy = np.asarray(layout.x, dtype=float) * MM
    inside = np.asarray(layout.phase) > 0
    area = _marker_area(layout)
    palette = colors(2)
    ax.scatter(xy[~inside, 0], xy[~inside, 1], s=area, color=palette[0], lw=0, gid=MATRIX,
               label=material_words("matrix", *cfg.matrix), zorder=1)
    ax.scatter(xy[inside, 0], xy[inside, 1], s=area, color=palette[1], lw=0, gid=INCLUSION,
               label=material_words("inclusion", *cfg.inclusion), zorder=2)
    ax.add_patch(_domain_patch(layout))
    _inclusion_outlines(ax, layout)
    pairs = np.asarray(layout.pairs).reshape(-1, 2)
    if pairs.size and pairs_visible(layout):
        ends = xy[pairs[:, 0]]
        ax.scatter(ends[:, 0], ends[:, 1], s=max(area, 4.0), marker="x", color="k", lw=0.6,
                   gid=PAIRS, zorder=5,
                   label=f"interface pairs, tied by {CONSTRAINT_WORDS[cfg.constraints]}")
    extra = _tension(ax, cfg, layout) if cfg.loading == "tension" else \
        _eigenstrain(ax, cfg, layout)
    ax.set_aspect("equal")
    ax.set(xlabel="x [mm]", ylabel="y [mm]")
    ax.margins(0.18)
    if title:
        ax.set_title(title, fontsize="medium")
    handles = ax.get_legend_handles_labels()[0] + extra
    fig.legend(handles=handles, fontsize="small", loc="outside lower center", markerscale=1.5,
               frameon=False)
    return fig


def write_scene_map(cfg: Config, layout: Layout, folder: Path, title: str = "",
                    name: str = FILE_NAME) -> Path:
    """``scene_map.png`` (or ``name``) of ``cfg`` in ``folder``, through
    ``uqflow.report.figure_path``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = figure_path(folder, name)
    return save_figure(draw_scene_map(cfg, layout, title), path)
