"""uqflow's Taylor method against Monte Carlo through the MPM solver, at a size CI affords
(the seed-scene comparison, docs/mpm_scenes.md, takes minutes and is a benchmark figure).

The 1-D hydrodynamic plate impact (studies/scenes/verify_plate_impact_coarse.toml) with a
random bulk sound speed C and Hugoniot slope S1: the shocked pressure p = ρ0 (C + S1 u_p) u_p
is linear in both, so a second-order Taylor expansion of the plateau's mean pressure has no
truncation error beyond the solver's own (ringing that moves smoothly with C and S1), and its
mean must agree with plain Monte Carlo within the Monte Carlo standard error. (Variances
are not compared: behind the front the pressure rings with a phase that moves with C, so the
pointwise variance is not the plateau's, and Taylor warns that its curvature there is not
step-stable.)"""

from __future__ import annotations

import numpy as np
import pytest

import uqflow

from .test_verification import SCENES

PLATEAU_FROM = 2.0e-6      # s: every realization's shock has passed both probes by then
MC_RUNS = 32

STUDY = """
name = "mpm-plate-{kind}"
solver = "mpm"
scene = "{scene}"
outputs = ["pressure"]
[[inputs]]
name = "steel.eos.C"
distribution = "normal"
mean = 4569.0
cv = 0.02
[[inputs]]
name = "steel.eos.S1"
distribution = "normal"
mean = 1.49
cv = 0.05
[method]
{method}
[execution]
workers = 0
seed = 11
[output]
path = "{output}"
"""
METHODS = {"taylor": 'kind = "taylor"\norder = 2',
           "mc": f'kind = "monte-carlo"\nsamples = {MC_RUNS}\nrule = "random"'}


def run(kind, tmp_path):
    path = tmp_path / f"{kind}.toml"
    path.write_text(STUDY.format(kind=kind, scene=SCENES / "verify_plate_impact_coarse.toml",
                                 method=METHODS[kind], output=tmp_path / f"{kind}.nc"))
    outcome = uqflow.run_study(uqflow.load_study(path))
    return uqflow.open_result(outcome.path)


def plateau(p):
    """The mean over both probes and the plateau's samples (a linear functional of the
    series, so it commutes with both methods' means)."""
    return p.sel(time=p.time >= PLATEAU_FROM).mean(("time", "probe"))


@pytest.mark.filterwarnings("ignore::uqflow.AccuracyWarning")
def test_taylor_mean_matches_monte_carlo(tmp_path):
    taylor, mc = run("taylor", tmp_path), run("mc", tmp_path)
    taylor_mean = float(plateau(taylor["statistics"]["pressure"].sel(statistic="mean")))
    per_run = plateau(mc["runs"]["pressure"]).values
    assert per_run.size == MC_RUNS and np.isfinite(per_run).all()
    mc_mean = per_run.mean()
    stderr = per_run.std(ddof=1) / np.sqrt(MC_RUNS)       # i.i.d. points (rule = "random")
    # the spread is the inputs' doing (C: 2 %, S1: 5 % → ≈ 1.5 % of p), not noise
    assert stderr > 1e-3 * abs(mc_mean)
    # 4 standard errors: a false alarm once in ~16,000 seeds; Taylor's own truncation is nil
    # for a pressure linear in C and S1 (the ringing's dependence is second order at most)
    assert abs(taylor_mean - mc_mean) < 4 * stderr
