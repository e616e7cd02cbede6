"""What the Johnson–Cook kernel records about its return (state.py: T_RETURN, RATE_STAR, DT,
EQ_STRAIN_RATE, SY_TOTAL_RATE), and the local (frozen-state) parameter derivatives built on it
(solvers/mpm/probe_sensitivities.py; docs/mpm_materials.md § 10)."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from solvers.mpm.materials import johnson_cook as jc, state as st
from solvers.mpm.solver import MPMSolver, _Run

REPO = Path(__file__).resolve().parents[3]
EPS = np.finfo(float).eps
# a shear rate that yields the 4340 steel in one step of DT_PLASTIC from rest
# (2G γ̇ dt = 2·81.8e9·5e4·1e-7 ≈ 0.8 GPa ≈ A/√3·1.8)
SHEAR_RATE, DT_PLASTIC = 5e4, 1e-7


def fresh(values=None):
    prm = jc.pack(values)
    S = st.new_state(1)
    assert jc.init(prm, S, 0) == st.OK
    return prm, S


def small_scene(**over):
    sc = tomllib.loads((REPO / "studies/scenes/mpm_contact_thin_small.toml").read_text())
    sc.update(resolution=0.5, end_time=8e-6, output_interval=1e-6, threads=1)
    sc.update(over)
    return sc


def test_init_records_the_reference_state():
    prm, S = fresh()
    assert S[0, st.T_RETURN] == prm[jc.I_TROOM] and S[0, st.RATE_STAR] == 1.0
    assert S[0, st.DT] == 0.0 and S[0, st.EQ_STRAIN_RATE] == 0.0
    assert S[0, st.SY_TOTAL_RATE] == S[0, st.SY] == prm[jc.I_JA]


def test_return_temperature_is_the_temperature_before_heating():
    prm, S = fresh()
    S[0, st.T] = 500.0
    assert jc.update(prm, S, 0, 0.0, SHEAR_RATE, SHEAR_RATE, 0.0, DT_PLASTIC, 0.0, 0.0, 0.0) \
        == st.OK
    assert S[0, st.EPS_P] > 0.0                       # plastic: heated
    assert S[0, st.T_RETURN] == 500.0 and S[0, st.T] > 500.0
    T_star = (500.0 - prm[jc.I_TROOM]) / (prm[jc.I_TMELT] - prm[jc.I_TROOM])
    dep = S[0, st.EPS_P]
    assert S[0, st.DT] == DT_PLASTIC and S[0, st.EPS_P_RATE] * S[0, st.DT] == pytest.approx(
        dep, rel=2 * EPS)                             # Δεp/Δt·Δt: two roundings
    # the recorded state reproduces the return's flow stress exactly (same formula, same args)
    assert S[0, st.SY] == jc.johnson_cook_flow_stress(
        *prm[[jc.I_JA, jc.I_JB, jc.I_JN, jc.I_JC, jc.I_JM]], dep, S[0, st.RATE_STAR], T_star)


def test_rate_star_is_the_clamped_plastic_rate():
    prm, S = fresh()
    # elastic step: ε̇* = 1 (the clamp); the total strain rate is still recorded
    L = (1e3, 0.0, 0.0, -1e3)
    assert jc.update(prm, S, 0, *L, 1e-9, 0.0, 0.0, 0.0) == st.OK
    assert S[0, st.EPS_P] == 0.0 and S[0, st.RATE_STAR] == 1.0
    D = np.array([1e3, -1e3, 0.0, 0.0])               # D′ (xx, yy, xy, zz), tr D = 0
    assert S[0, st.EQ_STRAIN_RATE] == pytest.approx(math.sqrt(2 / 3 * D @ D), rel=4 * EPS)
    # plastic steps: ε̇* = Δεp/(Δt ε̇0) when above 1 (fast), 1 when below (ε̇0 = 1e9 /s)
    for eps0, above in ((1.0, True), (1e9, False)):
        prm, S = fresh({"jc.eps0_dot": eps0})
        assert jc.update(prm, S, 0, 0.0, SHEAR_RATE, SHEAR_RATE, 0.0, DT_PLASTIC, 0.0, 0.0,
                         0.0) == st.OK
        rate = S[0, st.EPS_P] / (DT_PLASTIC * eps0)
        assert S[0, st.EPS_P] > 0.0 and (rate > 1.0) == above
        assert S[0, st.RATE_STAR] == (pytest.approx(rate, rel=2 * EPS) if above else 1.0)


def test_total_rate_flow_stress_has_no_elastic_jump():
    """SY drops back to the rate-free σy when a particle stops yielding; SY_TOTAL_RATE keeps
    the rate factor of the total strain rate (clamped ≥ 1) in both steps."""
    prm, S = fresh()
    A, B, n, C, m = prm[[jc.I_JA, jc.I_JB, jc.I_JN, jc.I_JC, jc.I_JM]]
    L = (0.0, SHEAR_RATE, SHEAR_RATE, 0.0)
    assert jc.update(prm, S, 0, *L, DT_PLASTIC, 0.0, 0.0, 0.0) == st.OK
    plastic = S[0].copy()
    # unload at the same strain rate magnitude (σeq falls by √3·2G·γ̇·dt ≈ 0.28 GPa): elastic
    assert jc.update(prm, S, 0, 0.0, -SHEAR_RATE, -SHEAR_RATE, 0.0, 2e-8, 0.0, 0.0, 0.0) \
        == st.OK
    assert S[0, st.EPS_P] == plastic[st.EPS_P] and S[0, st.RATE_STAR] == 1.0
    for row in (plastic, S[0]):
        T_star = (row[st.T_RETURN] - prm[jc.I_TROOM]) / (prm[jc.I_TMELT] - prm[jc.I_TROOM])
        rate = row[st.EQ_STRAIN_RATE] / prm[jc.I_EPS0]
        assert rate == pytest.approx(2 * SHEAR_RATE / math.sqrt(3), rel=4 * EPS)
        assert row[st.SY_TOTAL_RATE] == jc.johnson_cook_flow_stress(A, B, n, C, m,
                                                                    row[st.EPS_P], rate, T_star)
    jump_sy = S[0, st.SY] / plastic[st.SY] - 1.0
    jump_total = S[0, st.SY_TOTAL_RATE] / plastic[st.SY_TOTAL_RATE] - 1.0
    assert jump_sy < -0.05 and abs(jump_total) < 1e-3     # the 10 % jump, and none


def test_step_columns_in_a_run_sum_to_the_time():
    """In a scene run every steel particle records each step's Δt (their sum is the time), the
    temperature its return used and an ε̇* ≥ 1."""
    sol = MPMSolver.from_scene(small_scene())
    run = _Run(sol, sol._parameters({}))
    steel = sol.mat_index[sol.labels.index("steel")]
    total = np.zeros(steel.size)
    temps = []
    step = run._step

    def recording_step(dt, lap=None):
        before = run.S[steel, st.T].copy()
        step(dt, lap)
        total[:] += run.S[steel, st.DT]
        temps.append((before, run.S[steel, st.T_RETURN].copy()))
        assert np.all(run.S[steel, st.DT] == dt)

    run._step = recording_step
    run.advance()
    # bound: ~steps additions of positive dt, each rounding ≤ eps of the partial sum
    assert total == pytest.approx(np.full(steel.size, run.t), rel=run.step_no * EPS)
    assert all(np.array_equal(b, r) for b, r in temps)
    assert np.all(run.S[steel, st.RATE_STAR] >= 1.0)
    assert np.any(run.S[steel, st.EPS_P] > 0) and np.any(run.S[steel, st.T] > run.S[
        steel, st.T_RETURN])                          # some plastic heating happened
