"""What the reliability tests (issue 18) share: a study file of normal (or any) inputs with
``[[limit_states]]``, run through the executor with its accuracy warnings collected or
silenced, its result without the measured times, its file cut as a kill leaves it, its rounds
replayed; and the exact answers of the test problems (the paraboloid, the four-branch series
system)."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np
from scipy import integrate
from scipy import stats as sps

from uqflow.errors import AccuracyWarning
from uqflow.execute import run_study
from uqflow.layout import (ROUND, SENSITIVITY_COORD, SENSITIVITY_DIM, STATUS, STATUS_PENDING,
                           WALL_TIME)
from uqflow.report import open_result
from uqflow.store import read_runs, write_result
from uqflow.study import load_study

# ----------------------------------------------------------------------------- study files


def toml(value) -> str:
    """``value`` as a TOML value (inline tables for dicts)."""
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {toml(v)}" for k, v in value.items()) + " }"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(toml(v) for v in value) + "]"
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    if isinstance(value, (int, np.integer)):
        return repr(int(value))
    return repr(value)


def input_table(spec, k: int) -> dict:
    """An ``[[inputs]]`` table: ``spec`` itself if a dict, else a normal input in m from
    ``(mean, std)`` (named x{k + 1}) or ``(name, mean, std)``."""
    if isinstance(spec, dict):
        return spec
    name, mean, std = spec if len(spec) == 3 else (f"x{k + 1}", *spec)
    return {"name": name, "distribution": "normal", "mean": float(mean), "std": float(std),
            "units": "m"}


def study_file(tmp_path: Path, name: str, *, inputs, limit_states, method: dict,
               solver: str = "analytic", scene: dict | None = None, correlation=None,
               seed: int = 1, execution: dict | None = None) -> Path:
    """Write ``{name}.toml`` in ``tmp_path``: ``solver`` on ``scene``, the ``inputs`` (see
    ``input_table``) with an optional ``[correlation]`` matrix among them all, the
    ``[[limit_states]]`` tables, ``[method]``, ``[execution]`` (workers 0, ``seed``, then
    ``execution``'s keys) and a result ``{name}.nc`` without figures."""
    tables = [input_table(spec, k) for k, spec in enumerate(inputs)]
    lines = [f'name = "{name}"', f'solver = "{solver}"', f"scene = {toml(scene or {})}", ""]
    for table in tables:
        lines += ["[[inputs]]", *(f"{k} = {toml(v)}" for k, v in table.items()), ""]
    if correlation is not None:
        lines += ["[correlation]", f"inputs = {toml([t['name'] for t in tables])}",
                  f"matrix = {toml(np.asarray(correlation).tolist())}", ""]
    for table in limit_states:
        lines += ["[[limit_states]]", *(f"{k} = {toml(v)}" for k, v in table.items()), ""]
    lines += ["[method]", *(f"{k} = {toml(v)}" for k, v in method.items()), ""]
    execution = {"workers": 0, "seed": seed, **(execution or {})}
    lines += ["[execution]", *(f"{k} = {toml(v)}" for k, v in execution.items()), ""]
    lines += ["[output]", f'path = "{name}.nc"', "figures = false", ""]
    path = tmp_path / f"{name}.toml"
    path.write_text("\n".join(lines))
    return path


def run_warned(study, **kwargs):
    """``run_study`` of a study (or its file): the outcome and the messages of the
    AccuracyWarnings it raised."""
    if not hasattr(study, "method"):
        study = load_study(study)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        outcome = run_study(study, show_progress=False, force=True, **kwargs)
    return outcome, [str(w.message) for w in caught if issubclass(w.category, AccuracyWarning)]


def run_quietly(path, **kwargs):
    """``run_study`` of a study file, its AccuracyWarnings silenced."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        return run_study(load_study(path), show_progress=False, force=True, **kwargs)


def comparable(path):
    """A result's runs and statistics without what the executor measured (times)."""
    tree = open_result(path)
    runs = tree["runs"].to_dataset().drop_vars(["wall_time", "compile_time"], errors="ignore")
    stats = tree["statistics"].to_dataset()
    for key in ("solver_wall_time", "solver_compile_time"):
        stats.attrs.pop(key, None)
    return runs, stats


def cut_result(path, keep: int, pending, cut: Path, outputs=("y",)) -> Path:
    """The result file ``path`` as a study killed there would leave it, written to ``cut``:
    its first ``keep`` realizations, those at ``pending`` (indices) pending with NaN outputs,
    wall time and solver sensitivities, the file marked incomplete."""
    stored, attrs = read_runs(path)
    stored = stored.isel(realization=np.arange(keep))
    if SENSITIVITY_DIM in stored.dims:
        stored = stored.isel({SENSITIVITY_DIM: np.flatnonzero(
            stored[SENSITIVITY_COORD].values < keep)})
        undone = np.isin(stored[SENSITIVITY_COORD].values, pending)
        for var in stored.data_vars.values():
            if SENSITIVITY_DIM in var.dims and var.dtype.kind == "f":
                np.moveaxis(var.values, var.dims.index(SENSITIVITY_DIM), 0)[undone] = np.nan
    stored[STATUS].values[pending] = STATUS_PENDING
    for name in (*outputs, WALL_TIME):
        stored[name].values[pending] = np.nan
    attrs.update(complete=0)
    attrs.pop("runs_sha256", None)
    write_result(cut, stored, None, attrs)
    return cut


def assert_rounds_replay(method, runs, variables=("inputs",)) -> None:
    """A resume asks ``extend`` the same question of the same runs: every prefix of finished
    rounds gives back, bit for bit, the round that ran next (its ``variables``; NaN equal to
    NaN), and the whole asks for nothing more. ``method``: as planned, nothing extended."""
    rounds = runs[ROUND].values
    for r in range(int(rounds.max())):
        prefix = runs.isel(realization=np.flatnonzero(rounds <= r))
        more = method.extend(prefix, prefix)
        for name in variables:
            assert np.array_equal(more[name].values, runs[name].values[rounds == r + 1],
                                  equal_nan=True), (name, r + 1)
    assert method.extend(runs, runs) is None


# ----------------------------------------------------------------------------- exact answers

def paraboloid_exact(beta: float, kappa: float, n: int) -> float:
    """P[w > beta + kappa/2 Q] of the paraboloid g = beta - w + kappa/2 |v|^2 in n standard
    normals (w along the axis, v the n - 1 others): Q ~ chi2(n - 1) independent of
    w ~ N(0, 1), one quadrature to 1e-12 relative."""
    def integrand(q):
        return sps.norm.sf(beta + kappa / 2 * q) * sps.chi2.pdf(q, n - 1)
    # quadrature to its 1e-12 relative error estimate (smooth integrand)
    return integrate.quad(integrand, 0, np.inf, epsabs=0, epsrel=1e-12)[0]


def four_branch_margin(u, k: float = 6.0):
    """The four-branch series system (Waarts 2000; Au & Beck 2001) on rows u (u1, u2): the
    smallest of 3 + (u1 - u2)^2/10 -+ (u1 + u2)/sqrt 2 and +-(u1 - u2) + k/sqrt 2."""
    return np.minimum.reduce(list(four_branches(k)(np.asarray(u)).values()))


def four_branches(k: float = 6.0):
    """The four branches' margins g1 .. g4 of rows x (x1, x2) as a dict of arrays."""
    def function(x):
        s, d = (x[:, 0] + x[:, 1]) / math.sqrt(2), x[:, 0] - x[:, 1]
        return {"g1": 3 + d**2 / 10 - s, "g2": 3 + d**2 / 10 + s,
                "g3": d + k / math.sqrt(2), "g4": -d + k / math.sqrt(2)}
    return function


def four_branch_exact(k: float = 6.0) -> float:
    """1 - P[safe]: in a = (u1 + u2)/sqrt 2, b = (u1 - u2)/sqrt 2 (independent standard
    normals) the safe set is |a| < 3 + b^2/5, |b| < k/2, a one-dimensional integral (quad
    to 1e-13 relative)."""
    safe = integrate.quad(lambda b: sps.norm.pdf(b) * (1 - 2 * sps.norm.sf(3 + b * b / 5)),
                          # quadrature to its 1e-13 relative error estimate (smooth integrand)
                          -k / 2, k / 2, epsabs=0, epsrel=1e-13)[0]
    return 1.0 - safe
