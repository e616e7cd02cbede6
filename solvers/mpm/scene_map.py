"""A map of an MPM scene for the engineer who reads its results (docs/mpm_report.md, "The
scene map"): every body filled in its material's colour, a legend naming the materials in
words, every probe as a marker labelled with its name and position in mm, the grid's extent
with the kind of each side, the clamps and the detonation point; axes in mm.

Where the probes sit close together (the gauges in a 2 cm plate of a 2 m scene), a second
panel shows the region around them, so that each label can be read.
"""

from __future__ import annotations

from pathlib import Path

from solvers.mpm.scene import Config
from uqflow.report import colors, figure_path, new_figure, save_figure

#: A library material in words (the legend): the named materials of
#: solvers/mpm/materials/library.py. A material not listed is shown by its library name.
MATERIAL_WORDS = {
    "steel_4340": "AISI 4340 steel",
    "tnt": "TNT",
    "water": "water",
    "elastic": "elastic solid",
}
MM = 1e3                     # metres to millimetres
#: The probes get a panel of their own when the box around them (with its margin) is less
#: than this fraction of the domain's width and of its height: their labels would overlap.
ZOOM_BELOW = 0.2
ZOOM_MARGIN = 0.5            # the probe panel's margin, a fraction of the probes' extent
ZOOM_MIN_CELLS = 4           # ... and at least this many cells on each side
FILE_NAME = "scene_map"
LABEL_STEP = 13              # points between the heights of neighbouring probe labels
LABEL_LEVELS = 5             # heights used in turn


def material_words(cfg: Config, label: str) -> str:
    """A scene material in words, with the bodies made of it: "AISI 4340 steel: plate",
    "TNT: charge", "water" (a body named as its material is not said twice)."""
    material = cfg.materials[label]
    words = MATERIAL_WORDS.get(material.model, material.model.replace("_", " "))
    bodies = [b.name for b in cfg.bodies if b.material == label
              and b.name.replace("_", " ").lower() != words.lower()]
    return f"{words}: {', '.join(bodies)}" if bodies else words


def probe_words(name: str, x: float, y: float) -> str:
    """"probe H (x = 45, y = 0 mm)": a probe's name and its point in mm."""
    return f"probe {name} (x = {x * MM:.4g}, y = {y * MM:.4g} mm)"


def _body_patch(body, **style):
    from matplotlib.patches import Circle, Polygon, Rectangle

    g = body.geometry
    if body.shape == "rectangle":
        (x0, y0), (x1, y1) = g["min"], g["max"]
        return Rectangle((x0 * MM, y0 * MM), (x1 - x0) * MM, (y1 - y0) * MM, **style)
    if body.shape == "circle":
        (cx, cy), r = g["center"], g["radius"]
        return Circle((cx * MM, cy * MM), r * MM, **style)
    return Polygon(g["vertices"] * MM, closed=True, **style)


def _draw(ax, cfg: Config, fill: dict, label_probes: bool) -> None:
    from matplotlib.patches import Rectangle

    g = cfg.grid
    # bodies: the first body owns a lattice point it shares with a later one, so it is drawn
    # on top
    for k in reversed(range(len(cfg.bodies))):
        body = cfg.bodies[k]
        ax.add_patch(_body_patch(body, facecolor=fill[body.material], edgecolor="0.25",
                                 linewidth=0.6, zorder=1 + (len(cfg.bodies) - k) * 1e-3,
                                 label=f"body {body.name}", gid=f"body:{body.name}"))
    ax.add_patch(Rectangle((g.x0 * MM, g.y0 * MM), (g.x1 - g.x0) * MM, (g.y1 - g.y0) * MM,
                           fill=False, edgecolor="black", linestyle="--", linewidth=1.0,
                           zorder=3, gid="grid"))
    for c in g.clamps:
        ax.add_patch(Rectangle((c[0] * MM, c[1] * MM), (c[2] - c[0]) * MM,
                               (c[3] - c[1]) * MM, fill=False, hatch="xx", edgecolor="0.2",
                               linewidth=0.8, zorder=3, gid="clamp"))
    if cfg.detonation is not None:
        ax.plot([cfg.detonation[0] * MM], [cfg.detonation[1] * MM], marker="*",
                markersize=13, color="gold", markeredgecolor="black", linestyle="none",
                zorder=5, gid="detonation")
    # labels of probes side by side go to staggered heights, each with a leader line
    order = sorted(range(len(cfg.probes)), key=lambda k: (cfg.probes[k].point[1],
                                                          cfg.probes[k].point[0]))
    for rank, k in enumerate(order):
        p = cfg.probes[k]
        x, y = p.point
        ax.plot([x * MM], [y * MM], marker="o", markersize=5, color="black",
                markerfacecolor="white", linestyle="none", zorder=6, gid=f"probe:{p.name}")
        if label_probes:
            ax.annotate(f"{p.name} (x = {x * MM:.4g}, y = {y * MM:.4g} mm)", (x * MM, y * MM),
                        xytext=(8, 10 + LABEL_STEP * (rank % LABEL_LEVELS)),
                        textcoords="offset points", fontsize="small", zorder=7,
                        gid=f"probe-label:{p.name}",
                        arrowprops=dict(arrowstyle="-", color="0.3", linewidth=0.6),
                        bbox=dict(boxstyle="round,pad=0.15", facecolor="white", alpha=0.85,
                                  linewidth=0))
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")


def _side_words(ax, cfg: Config) -> None:
    """The kind of each side of the grid, written along it."""
    g = cfg.grid
    xm, ym = (g.x0 + g.x1) / 2 * MM, (g.y0 + g.y1) / 2 * MM
    places = {"left": (g.x0 * MM, ym, 90, "right", "center"),
              "right": (g.x1 * MM, ym, 270, "left", "center"),
              "bottom": (xm, g.y0 * MM, 0, "center", "top"),
              "top": (xm, g.y1 * MM, 0, "center", "bottom")}
    for side, (x, y, angle, ha, va) in places.items():
        ax.text(x, y, f"{side}: {g.sides[side]}", rotation=angle, ha=ha, va=va,
                fontsize="x-small", color="0.3", gid=f"side:{side}")


def _probe_box(cfg: Config):
    """(x0, x1, y0, y1) of the probe panel, or None when the probes read well on the map."""
    if not cfg.probes:
        return None
    g = cfg.grid
    xs = [p.point[0] for p in cfg.probes]
    ys = [p.point[1] for p in cfg.probes]
    pad = max(ZOOM_MARGIN * max(max(xs) - min(xs), max(ys) - min(ys)),
              ZOOM_MIN_CELLS * g.dx)
    box = (max(min(xs) - pad, g.x0), min(max(xs) + pad, g.x1),
           max(min(ys) - pad, g.y0), min(max(ys) + pad, g.y1))
    if box[1] - box[0] > ZOOM_BELOW * (g.x1 - g.x0) or \
            box[3] - box[2] > ZOOM_BELOW * (g.y1 - g.y0):
        return None
    return box


def draw_scene_map(cfg: Config, title: str = ""):
    """The figure of the scene ``cfg`` (see the module's docstring)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    zoom = _probe_box(cfg)
    fig, axes = new_figure(13.0 if zoom else 8.0, 6.0, 1, 2 if zoom else 1, squeeze=False,
                           sharex=False)
    axes = list(axes[0])
    fill = dict(zip(cfg.materials, colors(len(cfg.materials))))
    g = cfg.grid
    _draw(axes[0], cfg, fill, label_probes=zoom is None)
    _side_words(axes[0], cfg)
    margin = 0.04 * max(g.x1 - g.x0, g.y1 - g.y0) * MM
    axes[0].set_xlim(g.x0 * MM - margin, g.x1 * MM + margin)
    axes[0].set_ylim(g.y0 * MM - margin, g.y1 * MM + margin)
    axes[0].set_title(f"scene: grid of {g.ncx} × {g.ncy} cells of {g.dx * MM:.4g} mm",
                      fontsize="medium")
    if zoom is not None:
        from matplotlib.patches import Rectangle

        _draw(axes[1], cfg, fill, label_probes=True)
        axes[1].set_xlim(zoom[0] * MM, zoom[1] * MM)
        axes[1].set_ylim(zoom[2] * MM, zoom[3] * MM)
        axes[1].set_title("around the probes", fontsize="medium")
        axes[0].add_patch(Rectangle((zoom[0] * MM, zoom[2] * MM), (zoom[1] - zoom[0]) * MM,
                                    (zoom[3] - zoom[2]) * MM, fill=False, edgecolor="red",
                                    linewidth=1.0, zorder=8, gid="zoom"))
    handles = [Patch(facecolor=fill[label], edgecolor="0.25", label=material_words(cfg, label))
               for label in cfg.materials]
    handles.append(Patch(fill=False, edgecolor="black", linestyle="--",
                         label="grid (side kinds written along it)"))
    if g.clamps:
        handles.append(Patch(fill=False, hatch="xx", edgecolor="0.2",
                             label="clamped grid nodes"))
    if cfg.detonation is not None:
        handles.append(Line2D([], [], marker="*", markersize=11, color="gold",
                              markeredgecolor="black", linestyle="none",
                              label="detonation point"))
    if cfg.probes:
        handles.append(Line2D([], [], marker="o", markersize=5, color="black",
                              markerfacecolor="white", linestyle="none", label="probe"))
    fig.legend(handles=handles, fontsize="small", loc="outside lower center",
               ncols=min(len(handles), 4))
    if title:
        fig.suptitle(title)
    return fig


def write_scene_map(cfg: Config, folder: Path, title: str = "") -> Path:
    """``scene_map.png`` of ``cfg`` in ``folder`` (through ``uqflow.report.figure_path``)."""
    path = figure_path(Path(folder), FILE_NAME)
    path.parent.mkdir(parents=True, exist_ok=True)
    return save_figure(draw_scene_map(cfg, title), path)
