"""Checks of scene values shared by the solvers: each failure is a one-line SceneError naming
``scene.<key>`` (docs/study-files.md, "Errors")."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from uqflow.errors import SceneError

__all__ = ["is_number", "scene_error", "number", "integer", "number_pair", "table",
           "check_keys"]


def is_number(v):
    # TOML integers are unbounded in Python; one beyond float64 (|v| >= 2^1024) is no number
    # a solver can use.
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) \
        and not (isinstance(v, int) and abs(v) >= 2**1024)


def scene_error(key, reason):
    return SceneError(reason, key=f"scene.{key}")


def number(v, key, *, positive=False, lo=None, hi=None, nonnegative=False):
    if not is_number(v) or not math.isfinite(v):
        raise scene_error(key, f"must be a finite number, got {v!r}")
    v = float(v)
    if positive and v <= 0:
        raise scene_error(key, f"must be > 0, got {v!r}")
    if nonnegative and v < 0:
        raise scene_error(key, f"must be >= 0, got {v!r}")
    if lo is not None and v < lo:
        raise scene_error(key, f"must be >= {lo:g}, got {v!r}")
    if hi is not None and v > hi:
        raise scene_error(key, f"must be <= {hi:g}, got {v!r}")
    return v


def integer(v, key, lo, hi):
    if not isinstance(v, (int, np.integer)) or isinstance(v, bool):
        raise scene_error(key, f"must be an integer, got {v!r}")
    if v < lo:
        raise scene_error(key, f"must be >= {lo}, got {v!r}")
    if v > hi:
        raise scene_error(key, f"must be <= {hi:,}, got {v!r}")
    return int(v)


def number_pair(v, key):
    if (not isinstance(v, (list, tuple)) or len(v) != 2
            or not all(is_number(a) and math.isfinite(a) for a in v)):
        raise scene_error(key, f"must be a pair of finite numbers [a, b], got {v!r}")
    return float(v[0]), float(v[1])


def table(v, key):
    if not isinstance(v, Mapping):
        raise scene_error(key, f"must be a table, got {v!r}")
    return v


def check_keys(tbl, allowed, key):
    for k in tbl:
        if k not in allowed:
            raise scene_error(f"{key}.{k}" if key else k,
                       f"unknown key (takes {', '.join(sorted(allowed))})")
