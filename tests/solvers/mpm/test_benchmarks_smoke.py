"""The MPM scaling benchmarks at toy sizes, so they cannot rot (no speed is asserted): the
exact particle counts of the scaling part, its memory figure in a fresh process, and the
dask study in its --quick mode."""

import numpy as np
import pytest


@pytest.fixture
def throughput(monkeypatch, benchmark_module):
    import numba

    # the benchmark sets NUMBA_NUM_THREADS for its own process when imported: restored after
    monkeypatch.setenv("NUMBA_NUM_THREADS", str(numba.config.NUMBA_NUM_THREADS))
    return benchmark_module("mpm_throughput")


def test_scaling_counts_are_exactly_reachable(throughput, capsys):
    assert [throughput.cells_per_side(n) for n in throughput.COUNTS] == [50, 100, 200, 400, 500]
    # 10,001 is no 4 s²; 2,116 = 4 x 23² has too few cells for the plate; 40,004 is off by 4
    for count in (10_001, 2_116, 40_004):
        with pytest.raises(SystemExit) as stop:
            throughput.main(["--scaling-counts", "10000", str(count), "--no-write"])
        assert stop.value.code == 2
        error = capsys.readouterr().err.strip().splitlines()[-1]
        assert "--scaling-counts" in error and f"{count} particles" in error


def test_scaling_point_counts_at_least_the_run_arrays(throughput):
    point = throughput.scaling_in_child(10_000, 2, 1)
    assert "error" not in point, point.get("error")
    assert (point["particles"], point["cells_per_side"], point["threads"]) == (10_000, 50, 1)
    assert point["peak_reset"]
    assert set(point["first_call"]) == {"first_call_s", "numba_compile_s"}
    # The run writes every array it holds, so their pages are resident: the peak growth
    # cannot be below their bytes (it was, at 64 %, while the warm-up's freed heap was
    # reused unseen before malloc_trim).
    assert point["bytes_per_particle"] >= point["held_array_bytes_per_particle"] > 0


def test_dask_study_runs_in_quick_mode(monkeypatch, benchmark_module):
    module = benchmark_module("mpm_dask_study")
    monkeypatch.setattr(module, "write_section", lambda *a: pytest.fail("quick mode wrote"))
    result = module.main(["--quick"])
    in_process, on_dask = result["in_process"], result["dask"]
    assert result["particles"] == 4 * 100 * 50     # 2 m x 1 m at dx = 5 mm / 0.25, 2 x 2
    assert (in_process["concurrency"], on_dask["concurrency"]) == (1, 2)
    for variant in (in_process, on_dask):
        assert variant["ok"] == variant["realizations"] == 4
        # c workers, one realization at a time each, cannot run longer than c x the study
        assert variant["sum_run_wall_s"] <= variant["concurrency"] * variant["study_wall_s"]
        assert 0 <= variant["sum_run_compile_s"] <= variant["sum_run_wall_s"]
    assert result["identical_outputs"]                 # uqflow's results ignore the workers
    text = module.section(result)
    assert f"{on_dask['overhead_per_realization_s']:.2f} |" in text


def test_taichi_pairs_alternate_and_take_each_pairs_own_ratio(throughput, monkeypatch):
    # fakes whose speeds follow the machine's alternating slow spells, as (a)'s does: within a
    # set uqflow is twice Taichi and Taichi's step in numba 1.5 times, whatever the spell
    calls = []
    tick = iter([1.0, 2.0, 1.0, 2.0, 1.0, 2.0])
    slowness = [1.0]

    def fake_timed_steps(solver, steps, repeats):
        slowness[0] = next(tick)
        calls.append("uqflow")
        return [slowness[0] / 2] * repeats, 2

    def fake_taichi(n, steps, threads):
        calls.append("taichi")
        return {"particle_updates_per_s": n * steps / slowness[0]}

    def fake_numba(n, steps, repeats, threads):
        calls.append("numba")
        return {"particle_updates_per_s": 1.5 * n * steps / slowness[0]}

    monkeypatch.setattr(throughput, "timed_steps", fake_timed_steps)
    monkeypatch.setattr(throughput, "taichi", fake_taichi)
    monkeypatch.setattr(throughput, "minimal_in_numba", fake_numba)
    solver = type("S", (), {"parts": type("P", (), {"x": np.zeros(10)})})()
    args = type("A", (), {"pairs": 3, "steps": 4, "repeats": 5, "threads": 2})()
    pairs = throughput.taichi_pairs(solver, args)
    assert calls == ["uqflow", "taichi", "numba"] * 3
    assert [q["ratio"] for q in pairs] == [2.0, 2.0, 2.0]
    assert [q["numba_minimal_ratio"] for q in pairs] == [1.5, 1.5, 1.5]
    # Taichi at 40, 20, 40 particle-updates/s: the median is 40, the first such set
    assert throughput.median_pair(pairs) is pairs[0]
    # Taichi absent: one set, no ratio, and no further attempts
    calls.clear()
    monkeypatch.setattr(throughput, "taichi", lambda n, s, t: calls.append("taichi") or
                        {"error": "taichi not installed"})
    pairs = throughput.taichi_pairs(solver, args)
    assert calls == ["uqflow", "taichi"] and len(pairs) == 1 and pairs[0]["ratio"] is None


def test_taichis_minimal_step_in_numba_falls_freely_from_rest(benchmark_module):
    # From rest (v = 0, C = 0, J = 1) the grid momentum is zero, so every node with mass gets
    # v = dt g exactly; a particle whose stencil is clear of the sticky floor gathers
    # dt g Σw and an affine matrix 4/dx Σ w v (x_i - x_p), exactly dt g and 0 (the B-spline
    # reproduces constants and lines). Rounding: each weight to 4 ulp, 9 products and sums:
    # <= 32 ulp of dt g, and of 4/dx |dt g| max|x_i - x_p| (1.5 cells) for the matrix.
    mls = benchmark_module("numba_mlsmpm")
    state = mls.at_rest(4 * 16 * 16, threads=1)
    x, v, C, J, buf, grid_m, grid_v, dx, dt, p_vol, p_mass = state
    n, x0 = x.shape[0], x.copy()
    mls.substep(*state)
    eps = np.finfo(float).eps
    fall = dt * mls.GRAVITY
    assert grid_m.sum() == pytest.approx(n * mls.RHO * p_vol, rel=16 * eps * n)  # 9 n terms
    clear = np.floor(x0[:, 1] / dx - 0.5) >= mls.PAD
    assert 0 < clear.sum() < n
    assert np.all(v[:, 0] == 0.0)                       # nothing pushes sideways
    assert np.abs(v[clear, 1] - fall).max() <= 32 * eps * abs(fall)
    assert np.abs(C[clear]).max() <= 32 * eps * 4 / dx * abs(fall) * 1.5
    assert np.all(v[~clear, 1] > fall)                  # the floor holds the lowest ones back
    # one rounding of x + dt v, with x < 1.3
    np.testing.assert_allclose(x[:, 1], x0[:, 1] + dt * v[:, 1], rtol=0, atol=2 * eps)
