"""The particles a scene describes: its plate (or disc), its inclusions and their interface
pairs, as ``solvers.sph.layouts`` builds them from the resolved scene (``scene.Config``).

The solver builds its nominal layout and, for ``layout = "random"``, each realization's from
here; the scene map draws the same one.
"""

from __future__ import annotations

import math

import numpy as np

from solvers.sph.layouts import (Box, Ellipse, Layout, LayoutError, polar_layout, random_layout,
                                 regular_layout)
from solvers.sph.scene import Config, InclusionSpec
from uqflow.errors import SceneError

#: random sequential addition: placements tried per inclusion before giving up
ATTEMPTS_PER_INCLUSION = 2_000


def support_diameter(cfg: Config) -> float:
    """The support radius 2h, h = ratio * sqrt(spacing^2 / pi), known before the layout."""
    return 2.0 * cfg.smoothing_ratio * cfg.spacing / math.sqrt(math.pi)


def ellipse(spec: InclusionSpec) -> Ellipse:
    return Ellipse(spec.centre[0], spec.centre[1], spec.semi_axes[0], spec.semi_axes[1],
                   math.radians(spec.angle_deg))


def scene_layout(cfg: Config, seed: int | None = None) -> Layout:
    """The layout of ``cfg``; a random one drawn from ``seed`` (None: the scene's
    ``layout_seed``). A layout that cannot be built is a SceneError naming its key."""
    try:
        if cfg.layout == "polar":
            return polar_layout(cfg.inclusions[0].semi_axes[0], cfg.outer_radius, cfg.spacing)
        box = Box(-0.5 * cfg.width, -0.5 * cfg.height, 0.5 * cfg.width, 0.5 * cfg.height)
        if cfg.layout == "random":
            r = cfg.random
            rng = np.random.default_rng(r.layout_seed if seed is None else seed)
            return random_layout(box, cfg.spacing, r.count, (r.semi_axes_min, r.semi_axes_max),
                                 rng,
                                 # a gap in metres draws the same ellipses at every resolution
                                 # (levels of a study stay coupled)
                                 min_gap=r.min_gap or support_diameter(cfg),
                                 max_attempts=ATTEMPTS_PER_INCLUSION * r.count)
        layout = regular_layout(box, cfg.spacing, tuple(ellipse(s) for s in cfg.inclusions),
                                gap=cfg.gap)
        _check_clearance(layout, support_diameter(cfg))
        return layout
    except LayoutError as e:
        # a random layout's ellipses come from [random], not from inclusions[k]
        key = "random" if cfg.layout == "random" and e.key.startswith("inclusions") else e.key
        raise SceneError(str(e), key=f"scene.{key}") from None


def _check_clearance(layout: Layout, gap: float):
    """Inclusions one support apart from each other and from the edge: the seed's
    assumption (its eq. 20) that boundary and interface relations do not couple."""
    for k, e in enumerate(layout.inclusions):
        if e.distance_lower_bound(layout.domain) < gap:
            raise SceneError(f"closer than one support ({gap:.4g} m) to the plate's edge",
                             key=f"scene.inclusions[{k}]")
        for j in range(k):
            if e.distance_lower_bound(layout.inclusions[j]) < gap:
                raise SceneError(f"closer than one support ({gap:.4g} m) to inclusions[{j}]",
                                 key=f"scene.inclusions[{k}]")
