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

from . import jc_reference as jc_ref

REPO = Path(__file__).resolve().parents[3]
EPS = np.finfo(float).eps
# pow, exp, log: within ULP units in the last place on any CPU (numpy's AVX-512 loops ≤ 4)
ULP = 4
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
    # uniaxial strain rate: D′ = (2/3, −1/3, 0, −1/3)·ε̇, the plane-strain D′_zz counts
    L = (1e3, 0.0, 0.0, 0.0)
    assert jc.update(prm, S, 0, *L, 1e-9, 0.0, 0.0, 0.0) == st.OK
    assert S[0, st.EPS_P] == 0.0 and S[0, st.RATE_STAR] == 1.0
    D = np.array([2 / 3, -1 / 3, 0.0, -1 / 3]) * 1e3
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


# --- the consistent tangent: derivatives of one return against finite differences ------------
from solvers.mpm.materials.johnson_cook import johnson_cook_return_sensitivities  # noqa: E402

THETA_4340 = np.array([792e6, 510e6, 0.014, 0.26, 1.03])    # (A, B, C, n, m)
G_4340 = 81.8e9
FD_ETA = 1e-4            # relative parameter step of the central differences


def one_return(theta, trial, case):
    """(s (4,), Δεp, ε̇* used, σy) of ``jc_radial_return`` (or the fixed-rate variant) with
    parameters ``theta`` from the fixed ``trial`` deviator."""
    A, B, C, n, m = theta
    dt, eps0, ep, T_star, fixed = case
    if fixed is None:
        *s, dep, sy, code = jc.jc_radial_return(*trial, G_4340, dt, A, B, n, C, m, eps0, ep,
                                                T_star)
        rate = max(dep * (1.0 / (dt * eps0)), 1.0)
    else:
        *s, dep, sy, code = jc.jc_radial_return_fixed_rate(*trial, G_4340, A, B, n, C, m, ep,
                                                           T_star, fixed)
        rate = fixed
    assert code == st.OK
    return np.array(s), dep, rate, sy


def analytic_deviator_derivatives(theta, trial, case):
    """(s, ∂s/∂θ (4, 5), ∂²s/∂θ² (4, 5, 5), Δεp) from the return's own result."""
    s, dep, rate, sy = one_return(theta, trial, case)
    g, h = johnson_cook_return_sensitivities(*theta, G_4340, case[2] + dep, dep, rate, case[3],
                                             rate_fixed=case[4] is not None)
    ratio = s / sy
    return s, ratio[:, None] * g, ratio[:, None, None] * h, dep


def random_trial(rng, theta, case, overstress):
    A, B, C, n, m = theta
    d = rng.normal(size=4)
    d[3] = -d[0] - d[1]                                      # a plane-strain deviator
    ep, T_star, fixed = case[2], case[3], case[4]
    sy0 = (jc.johnson_cook_flow_stress(A, B, n, C, m, ep, 1.0, T_star) if fixed is None
           else jc.johnson_cook_flow_stress_seed(A, B, n, C, m, ep, fixed, T_star))
    return d * (overstress * sy0 / jc.von_mises(*d))


# (dt, ε̇0, εp_n, T*, fixed ε̇* or None): uqflow above the clamp (ε̇* ~ 1e4), clamped
# (ε̇0 = 1e12: ε̇* ~ 1e-5), seed conventions below and above ε̇0; εp_n = 0 (n < 1: infinite
# hardening slope at 0) and > 0; T* = 0 and > 0
RETURN_CASES = {
    "uqflow-rate-eps0": (1e-7, 1.0, 0.0, 0.0, None),
    "uqflow-rate-hardened-warm": (1e-7, 1.0, 0.05, 0.2, None),
    "uqflow-clamped-hardened-warm": (1e-7, 1e12, 0.05, 0.2, None),
    "uqflow-clamped-eps0": (1e-7, 1e12, 0.0, 0.0, None),
    "seed-slow-eps0": (1e-7, 1.0, 0.0, 0.0, 1e-3),
    "seed-fast-hardened": (1e-7, 1.0, 0.1, 0.0, 50.0),
    "seed-floor-hardened-warm": (1e-7, 1.0, 0.02, 0.3, 0.0),
}


@pytest.mark.parametrize("name", sorted(RETURN_CASES))
def test_consistent_tangent_matches_finite_differences_of_the_return(name):
    """∂s_ij/∂θ = (s_ij/σy)·3G/(3G + H)·∂σy/∂θ and its θ-derivative (the Hessian) against
    central differences of ``jc_radial_return`` from the same trial deviator, for plastic
    returns (overstress 1.01–2) and elastic ones (0.5–0.999: exactly 0, and the FD too).

    Tolerance of each FD: its truncation, estimated from the step-doubled difference
    (|D(2η) − D(η)|/3, Richardson), plus its noise, the return's residual bound
    RETURN_RTOL·σeq* (plus rounding) carried to s_ij and divided by the step; for the Hessian
    (differences of the analytic gradient at the perturbed returns) the noise is that of Δεp,
    (RETURN_RTOL·σeq*/K)/Δεp relative, amplified by ≤ 4 (the powers n − 1, n − 2 of εp)."""
    case = RETURN_CASES[name]
    case = (case[0], case[1], case[2], case[3], None if case[4] is None else
            max(case[4], jc.SEED_RATE_STAR_FLOOR))
    rng = np.random.default_rng(sorted(RETURN_CASES).index(name))   # reproducible per case
    theta = THETA_4340
    for trial_no in range(12):
        plastic = trial_no >= 3
        over = rng.uniform(1.01, 2.0) if plastic else rng.uniform(0.5, 0.999)
        trial = random_trial(rng, theta, case, over)
        seq = jc.von_mises(*trial)
        s, g, h, dep = analytic_deviator_derivatives(theta, trial, case)
        assert (dep > 0) == plastic
        if not plastic:
            assert not g.any() and not h.any()
        for k in range(5):
            def fd(eta, what):
                e = np.zeros(5)
                e[k] = eta * theta[k]
                if what == "s":
                    return (one_return(theta + e, trial, case)[0]
                            - one_return(theta - e, trial, case)[0]) / (2 * e[k])
                return (analytic_deviator_derivatives(theta + e, trial, case)[1]
                        - analytic_deviator_derivatives(theta - e, trial, case)[1]) / (2 * e[k])
            # first derivatives
            d1, d2 = fd(FD_ETA, "s"), fd(2 * FD_ETA, "s")
            noise = np.abs(s) / jc.von_mises(*s) * (jc.RETURN_RTOL + 16 * EPS) * seq / (
                FD_ETA * theta[k])
            tol = 2 * np.abs(d2 - d1) / 3 + 2 * noise
            assert np.all(np.abs(d1 - g[:, k]) <= tol), (name, trial_no, k, d1, g[:, k], tol)
            if not plastic:
                assert not d1.any()
                continue
            # second derivatives: differences of the analytic gradient
            h1, h2 = fd(FD_ETA, "g"), fd(2 * FD_ETA, "g")
            K = 3 * G_4340
            rel_noise = 4 * (jc.RETURN_RTOL * seq / K / dep + 16 * EPS)
            noise_h = rel_noise * np.max(np.abs(g)) / (FD_ETA * theta[k])
            tol_h = 2 * np.abs(h2 - h1) / 3 + 2 * noise_h
            assert np.all(np.abs(h1 - h[:, :, k]) <= tol_h), (name, trial_no, k)


# --- a whole run: per-probe derivatives from the recorded state -------------------------------
from solvers.mpm import probe_sensitivities as PS                                   # noqa: E402
from solvers.mpm.materials.mie_gruneisen import mie_gruneisen_pressure_value       # noqa: E402
from solvers.mpm.probe_sensitivities import JC_PARAMETERS, MG_PARAMETERS           # noqa: E402
from solvers.mpm.probe_sensitivities import ProbeSensitivities, particle_derivatives  # noqa: E402
from uqflow.errors import SolverError                                               # noqa: E402

SENS_OUTPUTS = ["pressure", "flow_stress", "flow_stress_total_rate", "S11", "S22", "S12", "S33"]
# rounding of a closed form re-evaluated in another order (~10 flops)
CLOSED_FORM_REL = 1e-14


def sensitivity_scene(**over):
    sc = small_scene(outputs=SENS_OUTPUTS + ["plastic_strain"], **over)
    sc["probes"] = sc["probes"] + [
        {"name": "W", "point": [0.1, 0.05], "body": "water"},
        {"name": "Havg", "point": [0.05, 0.0], "body": "plate", "radius": 0.012}]
    return sc


def run_recording(sol, wrt, outputs):
    """A run with derivatives recorded, returning the _Run (its final state) too."""
    prms = sol._parameters({})
    run = _Run(sol, prms)
    run.sensitivities = ProbeSensitivities(sol, prms, run.recorder.members, wrt, outputs,
                                           sol.times.size)
    run.advance()
    return run


@pytest.fixture(scope="module", params=["uqflow", "seed"])
def recorded(request):
    sol = MPMSolver.from_scene(sensitivity_scene(conventions=request.param))
    wrt = list(sol.local_sensitivities()["pressure"])
    outputs = SENS_OUTPUTS
    return sol, wrt, run_recording(sol, wrt, outputs), request.param


def test_local_sensitivities_lists_the_steel_parameters_for_its_outputs():
    sol = MPMSolver.from_scene(sensitivity_scene())
    local = sol.local_sensitivities()
    assert set(local) == set(SENS_OUTPUTS)                   # plastic_strain: a history
    assert all(v == tuple(f"steel.{p}" for p in MG_PARAMETERS + JC_PARAMETERS)
               for v in local.values())
    with pytest.raises(SolverError, match="'plastic_strain' has no local derivative.*taylor"):
        sol.run_with_sensitivities({}, ["steel.jc.A"], ["plastic_strain"])
    with pytest.raises(SolverError, match="'steel.eos.C'.*taylor"):
        sol.run_with_sensitivities({}, ["steel.jc.A", "steel.eos.C"], ["pressure"])
    sc = sensitivity_scene()
    sc["materials"]["steel"] = {"model": "elastic"}          # no MG-JC steel: no capability
    assert MPMSolver.from_scene(sc).local_sensitivities() == {}


def test_run_with_sensitivities_is_the_run_plus_the_recorded_derivatives(recorded):
    sol, wrt, run, _ = recorded
    outputs = ["pressure", "S12"]
    ds = sol.run_with_sensitivities({}, wrt[::-1], outputs)
    plain = sol.run({})
    for o in sol.cfg.outputs:
        assert np.array_equal(ds[o].values, plain[o].values), o   # the run itself untouched
    assert list(ds.parameter.values) == wrt[::-1] == list(ds.parameter_j.values)
    for o in outputs:
        assert ds[o + "__gradient"].dims == ("time", "probe", "parameter")
        assert ds[o + "__hessian"].dims == ("time", "probe", "parameter", "parameter_j")
        # the same deterministic run (one thread), parameters in reverse order
        assert np.array_equal(ds[o + "__gradient"].values,
                              run.sensitivities.gradient[o][:, :, ::-1])
        assert np.array_equal(ds[o + "__hessian"].values,
                              run.sensitivities.hessian[o][:, :, ::-1, ::-1])


def test_probe_derivatives_equal_closed_forms_of_the_recorded_state(recorded):
    """At the last output time, each single-particle probe's derivatives against closed forms
    evaluated from its particle's state columns (not the code under test): ∂σy/∂A = σy/h,
    ∂σy/∂B = εp^n σy/h, ∂σy/∂C = h ln ε̇*·t; the deviator's ∂s/∂A = (s/σy)·3G/(3G+H)·σy/h with
    H a central difference of the kernel's own flow stress in Δεp; the pressure's by complex
    step of eq. 10 at the recorded (μ, E), whose value is the P column."""
    sol, wrt, run, conventions = recorded
    sens = run.sensitivities
    k_steel = sol.labels.index("steel")
    prm = run.prms[k_steel]
    A, B, n, C, m = prm[[jc.I_JA, jc.I_JB, jc.I_JN, jc.I_JC, jc.I_JM]]
    G = prm[jc.I_G]
    seed = conventions == "seed"
    floor = jc.SEED_RATE_STAR_FLOOR if seed else 1.0
    col = {p: wrt.index(f"steel.{p}") for p in MG_PARAMETERS + JC_PARAMETERS}
    plastic_seen = 0
    for j, probe in enumerate(sol.cfg.probes):
        idx, w = run.recorder.members[j]
        if probe.name in ("W", "Havg"):
            continue
        (i,) = idx
        row = run.S[i]
        ep, sy = row[st.EPS_P], row[st.SY]
        g_sy = sens.gradient["flow_stress"][-1, j]
        T_star = (row[st.T_RETURN] - prm[jc.I_TROOM]) / (prm[jc.I_TMELT] - prm[jc.I_TROOM])
        f = jc_ref.factors(A, B, C, n, m, ep, row[st.RATE_STAR], T_star, floor)
        h = float(f.h)
        assert g_sy[col["jc.A"]] == pytest.approx(f.h_A * sy / h, rel=CLOSED_FORM_REL)
        assert g_sy[col["jc.B"]] == pytest.approx(f.h_B * sy / h, rel=CLOSED_FORM_REL)
        assert g_sy[col["jc.C"]] == pytest.approx(h * f.r_C * f.t, rel=CLOSED_FORM_REL, abs=0.0)
        # deviator through the tangent
        dep = row[st.EPS_P_RATE] * row[st.DT]
        if dep > 0:
            plastic_seen += 1
            ep_n = ep - dep
            k_rate = 1.0 / (row[st.DT] * prm[jc.I_EPS0])

            def flow(x):
                if seed:
                    return jc.johnson_cook_flow_stress_seed(A, B, n, C, m, ep_n + x,
                                                            row[st.RATE_STAR], T_star)
                return jc.johnson_cook_flow_stress(A, B, n, C, m, ep_n + x, x * k_rate, T_star)
            step = 1e-6 * dep
            H = (flow(dep + step) - flow(dep - step)) / (2 * step)
            s = st.deviatoric(row[None])[0]
            for name, c in (("S11", 0), ("S22", 1), ("S12", 2), ("S33", 3)):
                expected = s[c] / sy * 3 * G / (3 * G + H) * sy / h
                # central difference of H: truncation (1e-6)²·|F'''/F'|·Δ² ≲ 1e-12, rounding
                # eps·σy/(1e-6·Δ·H) ≲ 1e-9 relative to H, ≤ H/(3G+H) of that in the tangent
                assert sens.gradient[name][-1, j, col["jc.A"]] == pytest.approx(
                    expected, rel=1e-8)
        else:
            for name in ("S11", "S22", "S12", "S33"):
                assert not sens.gradient[name][-1, j].any() and not sens.hessian[name][-1, j].any()
        # pressure by complex step at the recorded state
        rho0 = prm[jc.I_RHO0]
        mu, E = row[st.RHO] / rho0 - 1.0, row[st.E]
        mg = prm[[jc.I_S1, jc.I_S2, jc.I_S3, jc.I_G0, jc.I_A]]
        value = mie_gruneisen_pressure_value(mu, E, rho0, prm[jc.I_C], *mg)
        # bound: p from ρ via μ = ρ/ρ0 − 1 and a few roundings of eq. 10 (as in test_sensitivities)
        assert value == pytest.approx(row[st.P], rel=1e-12, abs=1e-12 * abs(E))
        for q, p in enumerate(MG_PARAMETERS):
            z = mg.astype(complex)
            z[q] += 1e-30j * mg[q] if mg[q] != 0 else 1e-30j
            cs = mie_gruneisen_pressure_value(mu, E, rho0, prm[jc.I_C], *z).imag / (
                1e-30 * mg[q] if mg[q] != 0 else 1e-30)
            # complex step: no cancellation, only the rounding of eq. 10 (CS_RTOL of
            # test_sensitivities: 1e-10)
            assert sens.gradient["pressure"][-1, j, col[p]] == pytest.approx(cs, rel=1e-10,
                                                                             abs=1e-10 * abs(E))
    assert plastic_seen > 0


def test_derivatives_without_a_local_dependence_are_exactly_zero(recorded):
    sol, wrt, run, _ = recorded
    sens = run.sensitivities
    mg = [wrt.index(f"steel.{p}") for p in MG_PARAMETERS]
    jcp = [wrt.index(f"steel.{p}") for p in JC_PARAMETERS]
    water = [p.name for p in sol.cfg.probes].index("W")
    for o, g in sens.gradient.items():
        h = sens.hessian[o]
        assert not g[:, water].any() and not h[:, water].any(), o   # a probe in the water
        off = jcp if o == "pressure" else mg
        assert not g[..., off].any() and not h[..., off, :].any() and not h[..., off].any(), o
        assert np.array_equal(h, np.swapaxes(h, -1, -2)), o       # symmetric by construction
        assert np.all(np.isfinite(g)) and np.all(np.isfinite(h))
    # the reference state (t = 0): no pressure or deviator derivative; σy = A·(rate factor)
    for o in ("pressure", "S11", "S22", "S12", "S33"):
        assert not sens.gradient[o][0].any()
    plate = [j for j, p in enumerate(sol.cfg.probes) if p.name != "W"]
    rate_factor = sol.cfg.materials["steel"].values
    at_rest = 1.0 if rate_factor["seed_conventions"] == 0 else jc.SEED_RATE_STAR_FLOOR
    r0 = float(jc_ref.rate_factor(rate_factor["jc.C"], at_rest, floor=at_rest))
    # bound: r0 is 1 exactly (uqflow) or 1 + C ln(floor) (seed): numba's libm log against
    # numpy's (SIMD on AVX-512), each within ULP, grown by |C ln|/r0 in the sum, 1.5 roundings
    assert sens.gradient["flow_stress"][0, plate, wrt.index("steel.jc.A")] == pytest.approx(
        r0, rel=2 * (ULP * abs(r0 - 1.0) / r0 + 1.5) * EPS)


def test_averaging_probe_combines_its_members_derivatives(recorded):
    sol, wrt, run, _ = recorded
    j = [p.name for p in sol.cfg.probes].index("Havg")
    idx, w = run.recorder.members[j]
    assert idx.size > 1
    prm = run.prms[sol.labels.index("steel")]
    local = [wrt.index(f"steel.{p}") for p in PS.LOCAL_PARAMETERS]
    for o in ("flow_stress", "S11", "flow_stress_total_rate"):
        g, h = particle_derivatives(o, run.S[idx], prm)
        # bound: a weighted sum of ≤ 100 terms in another order, a few eps of Σ|w g|
        scale = np.abs(w) @ np.abs(g.reshape(idx.size, -1))
        got = run.sensitivities.gradient[o][-1, j][local]
        np.testing.assert_allclose(got, w @ g, rtol=0, atol=float(np.max(scale)) * 1e-13)


def test_total_rate_flow_stress_derivative_uses_the_total_rate(recorded):
    """``flow_stress_total_rate``: ∂/∂A = SY_TOTAL_RATE/h and ∂/∂C = h ln ε̇*_total·t, with
    ε̇*_total = EQ_STRAIN_RATE/ε̇0 clamped ≥ 1 (uqflow) or floored (seed)."""
    sol, wrt, run, conventions = recorded
    prm = run.prms[sol.labels.index("steel")]
    A, B, n, C, m = prm[[jc.I_JA, jc.I_JB, jc.I_JN, jc.I_JC, jc.I_JM]]
    steel = sol.mat_index[sol.labels.index("steel")]
    rows = run.S[steel]
    g, _ = particle_derivatives("flow_stress_total_rate", rows, prm)
    rate = rows[:, st.EQ_STRAIN_RATE] / prm[jc.I_EPS0]
    floor = jc.SEED_RATE_STAR_FLOOR if conventions == "seed" else 1.0
    T_star = (rows[:, st.T_RETURN] - prm[jc.I_TROOM]) / (prm[jc.I_TMELT] - prm[jc.I_TROOM])
    f = jc_ref.factors(A, B, C, n, m, rows[:, st.EPS_P], rate, T_star, floor)
    np.testing.assert_allclose(g[:, 5], f.h_A * rows[:, st.SY_TOTAL_RATE] / f.h,
                               rtol=CLOSED_FORM_REL)
    np.testing.assert_allclose(g[:, 7], f.h * f.r_C * f.t, rtol=CLOSED_FORM_REL, atol=0)
    if conventions == "seed":
        assert np.any(g[:, 7] < 0)                           # below ε̇0: C softens
