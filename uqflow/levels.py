"""Fidelity levels: one scene key, several values, coupled realizations across them.

A study's ``[levels]`` table names a scene key (``resolution``; dotted for a nested table,
``random.count``) and its values, coarsest first. Each value gives a scene and a solver; the
finest is the study's own (its outputs template lays out the runs). A design that uses
levels has an integer ``level`` per realization (an index into the values) and a
``seed_key`` per realization: rows with the same key are the same sample run at different
levels, so the executor gives them the same realization seed (the same random layout or
grid where a solver draws one) and the method the same inputs.

Outputs must be comparable across levels: each level's output template is checked against
the finest's when the study loads. ``align = "exact"`` asks for identical coordinates;
``align = "interpolate"`` interpolates a coarser level's outputs linearly onto the finest
level's numeric coordinates (time series on different output grids), refusing a point outside
the coarse level's range rather than extrapolating.
"""

from __future__ import annotations

import copy
import inspect
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import xarray as xr
from pydantic import BaseModel, ConfigDict, Field

from uqflow.errors import SceneError, SolverError, StudyError
from uqflow.layout import LEVEL, SEED_KEY

#: the design variables of a study with levels, by the names the fidelity methods import
#: (``uqflow.layout.LEVEL`` and ``SEED_KEY`` are their home)
LEVEL_VARIABLE, SEED_KEY_VARIABLE = LEVEL, SEED_KEY
#: most values a [levels] table takes
MAX_LEVELS = 16


class LevelsSpec(BaseModel):
    """The ``[levels]`` table of a study file."""

    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)

    key: str = Field(min_length=1, description="the scene key that sets the fidelity")
    values: list[int | float] = Field(min_length=2, max_length=MAX_LEVELS,
                                      description="its values, coarsest first")
    align: Literal["exact", "interpolate"] = "exact"


def scene_with(scene: Mapping, key: str, value) -> dict:
    """A copy of ``scene`` with the dotted ``key`` set to ``value`` (tables created as
    needed; a non-table in the way is a ``StudyError`` naming ``levels.key``)."""
    out = copy.deepcopy(dict(scene))
    node = out
    parts = key.split(".")
    for part in parts[:-1]:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise StudyError(f"scene key '{part}' is not a table, so '{key}' cannot be set",
                             key="levels.key")
        node = child
    node[parts[-1]] = value
    return out


@dataclass
class Levels:
    """The resolved levels of a study: a scene and a solver per value."""

    spec: LevelsSpec
    scenes: list[dict]
    solvers: list
    #: per level, {dim: finest-level coordinate values} to interpolate onto (empty: exact)
    alignments: list[dict] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.scenes)

    @property
    def values(self) -> list:
        return list(self.spec.values)

    def aligned_solver(self, level: int):
        """The solver of ``level``, its outputs on the finest level's coordinates."""
        solver = self.solvers[level]
        return AlignedSolver(solver, self.alignments[level]) if self.alignments[level] \
            else solver


def resolve_levels(spec: LevelsSpec, scene: dict, solver_class, outputs: list[str],
                   scene_label: str) -> Levels:
    """Build one solver per level and check their outputs against the finest's."""
    values = list(spec.values)
    if len(set(values)) != len(values):
        raise StudyError(f"values must differ, got {values}", key="levels.values")
    scenes, solvers = [], []
    for i in range(len(values)):
        solvers.append(level_solver(spec, scene, solver_class, i))
        scenes.append(scene_with(scene, spec.key, values[i]))
    finest = solvers[-1].outputs()
    alignments = [_alignment(solvers[i].outputs(), finest, outputs, i, values[i], spec)
                  for i in range(len(values))]
    return Levels(spec, scenes, solvers, alignments)


def level_solver(spec: LevelsSpec, scene: dict, solver_class, level: int):
    """The solver of ``level``: ``scene`` with the levels' key set to that level's value.

    A scene that fails only because of the levels is the levels' fault, named as such: an
    unknown key is ``levels.key``, a value the scene refuses (at that key or, through it, at
    another) ``levels.values``. A scene that fails the same way without the levels' value is
    its own fault: its ``SceneError`` is raised unchanged."""
    value = spec.values[level]
    try:
        return solver_class.from_scene(scene_with(scene, spec.key, value))
    except SceneError as exc:
        broke = exc.key or "scene"
        parts = spec.key.split(".")
        # the key or a table on its way ("random" of "random.count") the scene does not take
        own = {".".join(parts[:i]) for i in range(1, len(parts) + 1)}
        if broke.removeprefix("scene.") in own:
            if exc.reason.startswith("unknown key"):
                raise StudyError(f"'{spec.key}' is not a key of this scene: {exc.reason}",
                                 key="levels.key") from None
        elif _fails_alone(scene, solver_class, broke):
            raise
        raise StudyError(f"{spec.key} = {value!r} (level {level}) gives a bad scene: "
                         f"{broke}: {exc.reason}", key="levels.values") from None


def _fails_alone(scene: dict, solver_class, key: str) -> bool:
    """Whether ``scene`` as written (without the levels' value) fails at ``key`` too."""
    try:
        solver_class.from_scene(scene)
    except SceneError as exc:
        return (exc.key or "scene") == key
    return False


def _alignment(template: xr.Dataset, finest: xr.Dataset, outputs: list[str], level: int,
               value, spec: LevelsSpec) -> dict:
    where = f"level {level} ({spec.key} = {value!r})"
    target = {}
    for name in outputs:
        if name not in template.data_vars:
            raise StudyError(f"{where} has no output '{name}'", key="levels.values")
        mine, theirs = template[name], finest[name]
        if mine.dims != theirs.dims:
            raise StudyError(f"{where} gives '{name}' with dims {mine.dims}, the finest level "
                             f"{theirs.dims}", key="levels.values")
        for dim in mine.dims:
            a = np.asarray(mine[dim].values) if dim in mine.coords else None
            b = np.asarray(theirs[dim].values) if dim in theirs.coords else None
            if a is not None and b is not None and a.shape == b.shape and \
                    np.array_equal(a, b):
                continue
            if a is None and b is None and mine.sizes[dim] == theirs.sizes[dim]:
                continue
            numeric = a is not None and b is not None and a.dtype.kind in "iuf" and \
                b.dtype.kind in "iuf"
            if spec.align == "exact" or not numeric:
                how = "set levels.align = \"interpolate\"" if numeric else \
                    "its coordinates are not numbers, so they cannot be interpolated"
                raise StudyError(f"{where} gives '{name}' on other '{dim}' coordinates than "
                                 f"the finest level ({mine.sizes[dim]} against "
                                 f"{theirs.sizes[dim]} values): {how}", key="levels.align")
            if b.min() < a.min() or b.max() > a.max():
                raise StudyError(f"{where}: '{dim}' spans [{a.min():g}, {a.max():g}], which "
                                 f"does not cover the finest level's [{b.min():g}, "
                                 f"{b.max():g}]: interpolation would extrapolate",
                                 key="levels.align")
            target[dim] = b
    return target


class AlignedSolver:
    """A level's solver whose outputs come on the finest level's coordinates (linear
    interpolation along the dims in ``target``)."""

    def __init__(self, solver, target: dict):
        self.solver, self.target = solver, target
        self._seeded = "seed" in inspect.signature(solver.run).parameters
        self.name = getattr(solver, "name", "")

    def run(self, params, fields=None, seed=None):
        kwargs = {"seed": seed} if self._seeded and seed is not None else {}
        result = self.solver.run(params, fields, **kwargs) if fields else \
            self.solver.run(params, **kwargs)
        out = result.interp({d: v for d, v in self.target.items() if d in result.dims},
                            method="linear")
        for name, var in out.data_vars.items():
            if np.isnan(var.values).any() and not np.isnan(result[name].values).any():
                raise SolverError(f"output '{name}' could not be interpolated onto the finest "
                                  f"level's coordinates")
        return out

    def __getattr__(self, name):
        return getattr(self.solver, name)


def level_array(design: xr.Dataset) -> np.ndarray | None:
    """The ``level`` of each realization, or None for a design without levels."""
    if LEVEL not in design.variables:
        return None
    return np.asarray(design[LEVEL].values, dtype=np.int64)


def same_level_runs(indices: np.ndarray, levels: np.ndarray | None) -> list[np.ndarray]:
    """``indices`` cut into consecutive runs of one level each (one piece without levels)."""
    if levels is None or indices.size == 0:
        return [indices]
    lv = levels[indices]
    cuts = np.flatnonzero(np.diff(lv)) + 1
    return np.split(indices, cuts)
