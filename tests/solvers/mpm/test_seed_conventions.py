"""The scene option ``conventions = "seed"`` in the Johnson–Cook kernel (docs/mpm_materials.md
§ 3a), and the default (``"uqflow"``) left bit for bit as it was."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from solvers.mpm.solver import MPMSolver, _Run

from . import jc_reference as jc_ref
from .test_local_sensitivities import small_scene

REPO = Path(__file__).resolve().parents[3]
REFERENCE = REPO / "tests/data/mpm_uqflow_reference.npz"
REFERENCE_OUTPUTS = ["pressure", "flow_stress", "S11", "S22", "S12", "S33", "plastic_strain",
                     "temperature", "velocity_x"]


def test_uqflow_conventions_are_bitwise_unchanged():
    """tests/data/mpm_uqflow_reference.npz was written by the code before the state columns
    and the seed conventions existed (commit a1e4f98; the scene below, one thread): the probe
    series and a SHA-256 of the final positions, velocities and the first 15 state columns
    (the layout then) must be reproduced bit for bit."""
    ref = np.load(REFERENCE)
    sc = small_scene(end_time=15e-6, output_interval=0.5e-6, outputs=REFERENCE_OUTPUTS)
    sol = MPMSolver.from_scene(sc)
    ds = sol.run({})
    for name in REFERENCE_OUTPUTS + ["total_energy"]:
        assert np.array_equal(ds[name].values, ref[name]), name
    run = _Run(sol, sol._parameters({}))
    run.advance()
    digest = hashlib.sha256(np.ascontiguousarray(run.S[:, :15]).tobytes() + run.x.tobytes()
                            + run.y.tobytes() + run.vx.tobytes() + run.vy.tobytes()).hexdigest()
    assert digest == str(ref["state_sha256"])


# --- the kernel under the seed conventions --------------------------------------------------
from solvers.mpm.materials import johnson_cook as jc, state as st   # noqa: E402
from uqflow.errors import SceneError, SolverError                    # noqa: E402

EPS = np.finfo(float).eps
# pow and log: within ULP units in the last place on any CPU (numpy's AVX-512 loops ≤ 4)
ULP = 4


def rate_factor_rtol(C, rate_star):
    """Relative bound between two evaluations of 1 + C ln ε̇* with different logs (numba's
    libm, numpy's SIMD loops): each log within ULP, the product and the sum ½ eps each, the
    log's error magnified by the cancellation |C ln ε̇*|/(1 + C ln ε̇*) of the sum (37 at
    C = 0.047 and the floor ε̇* = 1e-9)."""
    c_log = C * np.log(rate_star)
    return 2 * ((ULP + 0.5) * np.abs(c_log) / (1.0 + c_log) + 0.5) * EPS
SEED = {"seed_conventions": 1.0, "jc.eps0_dot": jc.SEED_EPS0_DOT}


def fresh_seed(values=None):
    prm = jc.pack(dict(SEED, **(values or {})))
    S = st.new_state(1)
    assert jc.init(prm, S, 0) == st.OK
    return prm, S


def jc_args(prm):
    return prm[[jc.I_JA, jc.I_JB, jc.I_JN, jc.I_JC, jc.I_JM]]


@pytest.mark.numerics
@pytest.mark.parametrize("rate", [0.0, 1e-300, 1e-20, 1e-3, 1e4, 1e6, 1e12])
def test_seed_rate_factor_is_finite_and_positive_from_rest_to_huge_rates(rate):
    """ε̇_eq = 0 (ln → −∞, NaN when C = 0), tiny, at the floor, below and above ε̇0, huge: a
    pure shear at that rate, one step from rest; the state is finite and the rate factor is
    1 + C ln max(ε̇_eq/ε̇0, floor) > 0."""
    for C in (0.0, 0.014, 0.047):
        prm, S = fresh_seed({"jc.C": C})
        dt = min(1e-8, 1e-3 / rate) if rate > 0 else 1e-8    # shear strain per step ≤ 1e-3
        assert jc.update(prm, S, 0, 0.0, rate, rate, 0.0, dt, 0.0, 0.0, 0.0) == st.OK
        assert np.all(np.isfinite(S[0]))
        star = max(S[0, st.EQ_STRAIN_RATE] / jc.SEED_EPS0_DOT, jc.SEED_RATE_STAR_FLOOR)
        assert S[0, st.EQ_STRAIN_RATE] == pytest.approx(2 * rate / np.sqrt(3), rel=4 * EPS)
        assert S[0, st.RATE_STAR] == star
        factor = jc_ref.rate_factor(C, star, floor=jc.SEED_RATE_STAR_FLOOR)
        assert factor > 0.0
        A, B, n, _, m = jc_args(prm)
        assert S[0, st.SY] == jc.johnson_cook_flow_stress_seed(A, B, n, C, m, S[0, st.EPS_P],
                                                               star, 0.0)
        # the rate factor's bound, and per side εp^n within ULP, B·, A + and the product
        assert S[0, st.SY] == pytest.approx(jc_ref.hardening(A, B, n, S[0, st.EPS_P]) * factor,
                                            rel=rate_factor_rtol(C, star) + (2 * ULP + 3) * EPS)
        assert S[0, st.SY_TOTAL_RATE] == S[0, st.SY]         # the seed's return uses it
        if rate < jc.SEED_EPS0_DOT and C > 0:
            assert S[0, st.SY] < A                           # rate factor < 1 below ε̇0
        # the factor itself, called below the floor (ε̇* = 0, tiny): floored, finite
        assert jc.seed_rate_factor(C, S[0, st.EQ_STRAIN_RATE] / jc.SEED_EPS0_DOT) == \
            pytest.approx(factor, rel=rate_factor_rtol(C, star))   # numba's log, numpy's


def test_seed_fixed_rate_return_solves_the_consistency_condition():
    """Plastic steps at a fixed rate: σeq* − 3GΔεp = σy(εp_n + Δεp, ε̇*, T*) to the return's
    1e-13 residual, the deviator on that surface, for εp_n = 0 (n < 1: infinite slope) and
    > 0, rates below and above ε̇0, T* = 0 and > 0."""
    rng = np.random.default_rng(9)
    G = jc.PARAMETERS["shear_modulus"]
    A, B, n, C, m = jc_args(jc.pack())
    for _ in range(200):
        ep = 0.0 if rng.random() < 0.3 else 10.0 ** rng.uniform(-6, 0)
        star = 10.0 ** rng.uniform(-12, 3)
        T_star = 0.0 if rng.random() < 0.5 else rng.uniform(0, 0.9)
        sy0 = jc.johnson_cook_flow_stress_seed(A, B, n, C, m, ep, star, T_star)
        d = rng.normal(size=4)
        d[3] = -d[0] - d[1]                                  # traceless in-plane + zz
        d *= sy0 * rng.uniform(1.0 + 1e-9, 3.0) / jc.von_mises(*d)
        *s, dep, sy, code = jc.jc_radial_return_fixed_rate(*d, G, A, B, n, C, m, ep, T_star,
                                                           star)
        assert code == st.OK and dep > 0.0
        seq = jc.von_mises(*d)
        assert sy == jc.johnson_cook_flow_stress_seed(A, B, n, C, m, ep + dep, star, T_star)
        # bound: the return's residual test RETURN_RTOL·σeq* plus the rounding of the
        # final σy re-evaluation (a few eps of σeq*)
        assert abs(seq - 3 * G * dep - sy) <= (jc.RETURN_RTOL + 8 * EPS) * seq
        assert jc.von_mises(*s) == pytest.approx(sy, rel=8 * EPS)   # scaling: a few roundings


@pytest.mark.numerics
def test_seed_scene_run_has_no_heating_and_slow_rate_softening():
    sc = small_scene(conventions="seed")
    sol = MPMSolver.from_scene(sc)
    assert sol.nominal()["steel.jc.eps0_dot"] == jc.SEED_EPS0_DOT
    run = _Run(sol, sol._parameters({}))
    run.advance()
    steel = sol.mat_index[sol.labels.index("steel")]
    S = run.S[steel]
    assert np.all(np.isfinite(run.S))
    T_room = jc.PARAMETERS["jc.T_room"]
    assert np.all(S[:, st.T] == T_room) and np.all(S[:, st.T_RETURN] == T_room)
    assert np.any(S[:, st.EPS_P] > 0) and np.any(S[:, st.PLASTIC_WORK] > 0)
    slow = S[:, st.EQ_STRAIN_RATE] < jc.SEED_EPS0_DOT
    assert slow.any()
    np.testing.assert_array_equal(S[:, st.RATE_STAR], np.maximum(
        S[:, st.EQ_STRAIN_RATE] / jc.SEED_EPS0_DOT, jc.SEED_RATE_STAR_FLOOR))
    A, B, n, C, m = jc_args(run.prms[sol.labels.index("steel")])
    hard = jc_ref.hardening(A, B, n, S[:, st.EPS_P])
    factor = S[:, st.SY] / hard
    assert np.all(factor[slow] < 1.0)                        # the rate factor below ε̇0
    # numba's σy over numpy's hardening: the rate factor's bound, εp^n within ULP on each
    # side with B·, A + (ULP + 1 each), the product and the division
    expected = jc_ref.rate_factor(C, S[:, st.RATE_STAR], floor=jc.SEED_RATE_STAR_FLOOR)
    bound = rate_factor_rtol(C, S[:, st.RATE_STAR]) + (2 * ULP + 3) * EPS
    assert (np.abs(factor - expected) <= bound * np.abs(expected)).all()


def test_seed_conventions_parameter_rules():
    with pytest.raises(SolverError, match="jc.C"):
        jc.pack(dict(SEED, **{"jc.C": 0.05}))                # 1 + C ln 1e-9 < 0
    jc.pack({"jc.C": 0.05})                                  # fine with the clamp
    with pytest.raises(SolverError, match="seed_conventions"):
        jc.pack({"seed_conventions": 0.5})
    sc = small_scene(conventions="seed")
    sc["materials"]["steel"]["jc"] = {"eps0_dot": 1.0}       # the scene's own ε̇0 is kept
    assert MPMSolver.from_scene(sc).nominal()["steel.jc.eps0_dot"] == 1.0
    sc = small_scene()
    sc["materials"]["steel"]["seed_conventions"] = 1.0
    with pytest.raises(SceneError, match="materials.steel.seed_conventions"):
        MPMSolver.from_scene(sc)


def test_documented_seed_constants():
    """The numbers of docs/mpm_materials.md § 3a: ε̇0 = 1e6 /s, the floor 1e-9 (1e-3 /s at
    ε̇0), the negative-factor threshold e^(−1/C) ≈ 1e-31 at C = 0.014, the factor's lower bound
    1 − 20.7 C and the largest C, 0.048 (both printed to 3 and 2 digits)."""
    assert jc.SEED_EPS0_DOT == 1e6 and jc.SEED_RATE_STAR_FLOOR == 1e-9
    assert jc.SEED_RATE_STAR_FLOOR * jc.SEED_EPS0_DOT == pytest.approx(1e-3, rel=4 * EPS)
    assert round(np.log10(np.exp(-1 / 0.014))) == -31
    assert -np.log(jc.SEED_RATE_STAR_FLOOR) == pytest.approx(20.7, abs=0.05)
    assert -1 / np.log(jc.SEED_RATE_STAR_FLOOR) == pytest.approx(0.048, abs=0.0005)


# --- scene constants every run would refuse: refused at load -------------------------------
from solvers.mpm.scene import parse   # noqa: E402


def test_seed_rate_constant_is_refused_at_scene_load():
    """jc.C = 0.05 in the scene under the seed conventions used to validate and then fail every
    run that does not sample C (the rate factor's floor needs C < 1/ln 1e9 = 0.048): it is now
    one SceneError at load, naming the key; with the clamp (default conventions) it is fine."""
    sc = small_scene(conventions="seed")
    sc["materials"]["steel"]["jc"] = {"C": 0.05}
    with pytest.raises(SceneError) as e:
        parse(sc)
    assert e.value.key == "scene.materials.steel.jc.C"
    assert "seed conventions" in str(e.value) and "0.04825" in str(e.value)
    assert "\n" not in str(e.value)
    sc["conventions"] = "uqflow"
    assert parse(sc).materials["steel"].values["jc.C"] == 0.05
    sc = small_scene(conventions="seed")
    sc["materials"]["steel"]["jc"] = {"C": 0.04}                 # below the bound: accepted
    assert parse(sc).materials["steel"].values["seed_conventions"] == 1.0


def test_validate_refuses_the_seed_rate_constant_in_one_line(tmp_path, capsys):
    from uqflow.cli import main

    sc = (REPO / "studies/scenes/mpm_contact_thin_small_seed.toml").read_text()
    sc = sc.replace('model = "steel_4340"\n', 'model = "steel_4340"\njc.C = 0.05\n', 1)
    (tmp_path / "scene.toml").write_text(sc)
    study = (REPO / "studies/smpm/thin_jc_seed_conventions_cv0.10_taylor_local.toml").read_text()
    study = study.replace("../scenes/mpm_contact_thin_small_seed.toml", "scene.toml")
    (tmp_path / "study.toml").write_text(study)
    assert main(["validate", str(tmp_path / "study.toml")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "scene.materials.steel.jc.C" in err, err
