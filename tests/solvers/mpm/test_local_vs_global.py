"""What the seed's frozen-state derivatives (`taylor-local`) leave out against whole-solver
ones (`taylor`): the statements of docs/mpm_scenes.md, "One run or 2n+1: what the frozen state
misses", checked on a short coarse run of the thin plate (resolution 0.5, 38 µs: the probe H
has yielded and starts to unload elastically at ≈ 35 µs) with central differences in A.
The measured sizes over 100 µs are benchmark figures (benchmarks/smpm_local_vs_global.py)."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from solvers.mpm.solver import MPMSolver

REPO = Path(__file__).resolve().parents[3]
A_MEAN = 792.0e6
STEP = 0.1 * A_MEAN              # 1 std at the seed's C.V. 0.10
OUTPUTS = ["pressure", "flow_stress", "S11", "S22"]


@pytest.fixture(scope="module")
def runs():
    scene = tomllib.loads((REPO / "studies/scenes/mpm_contact_thin_small.toml").read_text())
    scene.update(resolution=0.5, end_time=38e-6, output_interval=0.5e-6, threads=1,
                 outputs=OUTPUTS + ["plastic_strain"])
    sol = MPMSolver.from_scene(scene)
    local = sol.run_with_sensitivities({}, ["steel.jc.A"], OUTPUTS)
    up = sol.run({"steel.jc.A": A_MEAN + STEP})
    down = sol.run({"steel.jc.A": A_MEAN - STEP})
    return local, up, down


def whole_solver_derivative(runs, output):
    _, up, down = runs
    return (up[output].values - down[output].values) / (2 * STEP)


def frozen_derivative(runs, output):
    return runs[0][f"{output}__gradient"].sel(parameter="steel.jc.A").values


def test_pressure_depends_on_a_only_through_the_history(runs):
    """The Mie-Grueneisen pressure has no A in it: its frozen derivative is exactly 0, while
    A changes the plate's motion and so the pressure a probe sees."""
    assert not frozen_derivative(runs, "pressure").any()
    whole = whole_solver_derivative(runs, "pressure")
    # One std of A moves the probes' pressure by far more than rounding (~1e-16 of 10 GPa):
    # at least 1 % of the nominal peak at some point.
    peak = np.abs(runs[0]["pressure"].values).max()
    assert np.abs(whole).max() * STEP > 0.01 * peak


def test_a_stronger_steel_deforms_less_and_the_frozen_derivative_misses_it(runs):
    """After yield (from 8 µs on, at every probe), dεp/dA < 0 — a larger A yields later and
    flows less — and the whole-solver dσy/dA, which includes that smaller plastic strain
    (through the hardening term B εp^n) and its smaller rate (through the rate factor), lies
    below the frozen-state dσy/dA, which holds εp and its rate fixed. (With B = 0 the gap
    stays positive through the rate factor alone; how much the hardening term explains is a
    benchmark figure.)"""
    local = runs[0]
    late = local["time"].values >= 8e-6
    eps = local["plastic_strain"].values[late]
    assert (eps > 0).all()
    assert (whole_solver_derivative(runs, "plastic_strain")[late] < 0).all()
    gap = frozen_derivative(runs, "flow_stress")[late] - \
        whole_solver_derivative(runs, "flow_stress")[late]
    assert (gap > 0).all()


def test_the_deviator_has_no_frozen_derivative_in_an_elastic_unloading_step(runs):
    """Once a yielded probe unloads elastically its S11, S22 no longer depend locally on the
    Johnson-Cook parameters (the return is inactive): frozen derivative exactly 0. The stress
    it unloads from was set by A, so the whole-solver derivative is not."""
    local = runs[0]
    h = list(local["probe"].values).index("H")
    eps = local["plastic_strain"].values[:, h]
    for output in ("S11", "S22"):
        frozen = frozen_derivative(runs, output)[:, h]
        unloading = (frozen == 0) & (eps > 0)
        assert unloading.sum() >= 3, output            # H unloads from ≈ 35 µs on
        spread = np.abs(whole_solver_derivative(runs, output)[:, h][unloading]) * STEP
        # one std of A moves the unloading deviator by more than 1 % of its size there
        assert (spread > 0.01 * np.abs(local[output].values[:, h][unloading])).all(), output
