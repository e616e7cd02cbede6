"""Shared helpers of the gamut_bar tests: cached runs (a run is deterministic), the
Ramberg–Osgood reference and a stand-in for uqflow.fields.FieldSample."""

from __future__ import annotations

import functools

import numpy as np

from solvers.gamut_bar import GamutBarSolver
from solvers.gamut_bar.materials import MATERIALS, ro_stress

EPS = float(np.finfo(float).eps)   # unit roundoff × 2: the scale of every rounding bound below


def solver(**scene):
    return GamutBarSolver.from_scene(scene)


def small_solver(loading: str):
    """A 40-bond bar under ``loading``; a cyclic one through 3 cycles, each once."""
    cyclic = {"cycles": 3, "cycle_repeats": 1} if loading == "cyclic" else {}
    return solver(loading=loading, local_bonds=40, **cyclic)


def field_table(name: str, parameters: str, *, correlation_length: float,
                captured_variance: float, store_values: bool | None = None) -> str:
    """A study's ``[[fields]]`` table for the bar (``parameters`` as TOML text): exponential
    kernel, symmetric Weibull germ of scale 1 and shape 2, divisor 10."""
    text = f"""
[[fields]]
name = "{name}"
parameters = {parameters}
kernel = "exponential"
correlation_length = {correlation_length}
captured_variance = {captured_variance}
germ = {{ kind = "symmetric-weibull", scale = 1.0, shape = 2.0 }}
divisor = 10
"""
    if store_values is not None:
        text += f"store_values = {'true' if store_values else 'false'}\n"
    return text


@functools.lru_cache(maxsize=None)
def _cached(scene_items, params_items):
    return solver(**dict(scene_items)).run(dict(params_items))


def run(params=None, **scene):
    """A deterministic run, computed once per (scene, params) in the session."""
    return _cached(tuple(sorted(scene.items(), key=lambda kv: kv[0])),
                   tuple(sorted((params or {}).items())))


def material(name="M1", **overrides):
    m = dict(MATERIALS[name])
    m.update(overrides)
    return m


def ro(strain, m):
    """Ramberg–Osgood stress at each strain (inverted by bisection)."""
    return np.array([ro_stress(e, m["E"], m["sigma_y"], m["n_ro"], m["K_ro"])
                     for e in np.atleast_1d(strain)])


class FakeFields(dict):
    """Mapping parameter -> f(x) giving the multiplier of the mean; ``values`` as the real
    FieldSample: mean × f(points), clipped into [lower, upper] unless ``clip`` is False."""

    def __init__(self, patterns, clip=True):
        super().__init__(patterns)
        self.clip = clip
        self.calls = []

    def values(self, parameter, points, mean, lower, upper):
        self.calls.append((parameter, np.asarray(points).size, mean, lower, upper))
        v = np.asarray(mean) * self[parameter](np.asarray(points, dtype=float))
        return np.clip(v, lower, upper) if self.clip else v
