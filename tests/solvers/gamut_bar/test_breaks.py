"""A bar that breaks during the cyclic loading is an outcome (issue 18, point 1): broken,
the cycle and the bond, status ok for a study that stores what a broken bar has; a step
Newton cannot carry stays a failed realization; Monte Carlo counts the breaks as failure
events and keeps the failed realizations apart."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

import solvers.gamut_bar.solver as bar_solver
from uqflow.errors import StudyError
from uqflow.layout import NO_VALUE_REASON
from uqflow.realization import run_one
from uqflow.study import load_study

from ._common import FakeFields, solver

# M2 (sigma_f only 1.08 sigma_y) on 20 bonds, three amplitude levels of two cycles each: six
# cycles of 400 steps, 0.05 s a run. A bond whose R is 0.5 of the bar's breaks the bar on
# the ramp to the third level; at 0.6 it survives the cycles (found by running both).
SCENE = dict(material="M2", loading="cyclic", local_bonds=20, cycles=3, cycle_repeats=2,
             amplitude_range=[1.0, 1.06])
CYCLES = 6
SOFT_SPOT = 0.0375                       # midpoint of bond 7


def soft_R(factor):
    return FakeFields({"bar.R": lambda x: np.where(np.abs(x - SOFT_SPOT) < 1e-9, factor, 1.0)})


def bar():
    return solver(**SCENE)


def troughs(stress):
    """Load steps where the stress turns from falling to rising: one per finished half loop
    (the force goes down to -sigma_a and back)."""
    s = stress[np.isfinite(stress)]
    return int(np.sum((s[1:-1] < s[:-2]) & (s[1:-1] < s[2:])))


def test_a_bar_that_breaks_in_the_cycles_reports_broken_cycle_and_bond():
    sol = bar()
    ds = sol.run({}, soft_R(0.5))
    assert ds["broken"].item() == 1.0
    stress, m = ds["stress"].values, sol.props
    broke_at = int(np.flatnonzero(np.isnan(stress))[0])      # the step that did not hold
    # the last step of the ramp to the third level (1 + 100 + 2 x 400 + 3 + 2 x 400 + 2:
    # docs/reliability.md quotes it)
    assert broke_at == 1706
    assert np.isfinite(stress[:broke_at]).all() and np.isnan(stress[broke_at:]).all()
    # the path holds four finished loops (two levels, two cycles each) and broke in the
    # fifth cycle, on its ramp: the stress at the break lies between the second and third
    # amplitudes (force controlled: the prescribed force at the break, bisected)
    amplitudes = np.geomspace(1.0 * m["sigma_y"], 1.06 * m["sigma_y"], 3)
    assert troughs(stress) == 4 and ds["break_cycle"].item() == 4 + 1
    assert amplitudes[1] < ds["failure_stress"].item() <= amplitudes[2]
    # the bond that broke is the most strained one at the failure state, just within eps_f
    # there (the bisection leaves the largest force that holds)
    strains = ds["bond_strain"].values
    bond = int(ds["break_bond"].item())
    assert bond == int(np.argmax(np.abs(strains)))
    assert 0.99 * m["eps_f"] < strains[bond] <= m["eps_f"]
    x = ds["x"].values
    assert ds["break_position"].item() == 0.5 * (x[bond] + x[bond + 1])
    # the loops finished before the break keep their amplitudes; n' and K' have no value
    assert np.isfinite(ds["stress_amplitude"].values[:2]).all()
    assert np.isnan(ds["stress_amplitude"].values[2]) and np.isnan(ds["n_prime"].item())
    assert ds.attrs[NO_VALUE_REASON].startswith(
        f"the bar broke in cycle 5 of {CYCLES}, cyclic step {broke_at} ")
    assert f"(bond {bond}, x = " in ds.attrs[NO_VALUE_REASON]


def test_a_bar_that_survives_the_cycles_broke_in_the_pull_after_them():
    ds = bar().run({}, soft_R(0.6))
    assert ds["broken"].item() == 0.0
    assert ds["break_cycle"].item() == CYCLES + 1 == \
        ds["break_cycle"].attrs["not_within_loading"]
    assert np.isfinite(ds["stress"].values).all() and np.isfinite(ds["n_prime"].item())
    assert troughs(ds["stress"].values) == CYCLES
    bond = int(ds["break_bond"].item())
    assert bond == int(np.argmax(np.abs(ds["bond_strain"].values)))
    assert NO_VALUE_REASON not in ds.attrs


def test_the_realization_is_ok_when_the_study_stores_what_a_broken_bar_has():
    sol, fields = bar(), soft_R(0.5)
    status, message, values, _ = run_one(sol, {}, fields, ["broken", "break_cycle",
                                                          "break_bond", "failure_strain"])
    assert (status, message) == ("ok", "")
    assert values["broken"] == 1.0 and values["break_cycle"] == 5.0
    # a study storing the path keeps the broken bar failed, saying where it broke
    status, message, _, _ = run_one(sol, {}, fields, ["broken", "stress"])
    assert status == "failed"
    assert message.startswith("non-finite output 'stress': the bar broke in cycle 5 of 6, "
                              "cyclic step ")
    assert "local strain beyond eps_f (bond " in message


def test_a_step_newton_cannot_carry_in_the_cycles_stays_a_failed_realization(monkeypatch):
    # two Newton iterations are too few once the bonds slip (step 87 of the first ramp):
    # the solver's failure, not the bar's, whatever the study stores
    monkeypatch.setattr(bar_solver, "MAXIT", 2)
    status, message, values, _ = run_one(bar(), {}, None, ["broken", "break_cycle"])
    assert status == "failed" and values == {}
    assert message.startswith("SolverError: cyclic step ") and \
        "Newton did not converge" in message


def test_the_template_says_what_a_break_leaves_and_when_the_cycles_end():
    template = bar().outputs()
    assert template["broken"].attrs["flag_values"].tolist() == [0, 1]
    assert template["break_cycle"].attrs["not_within_loading"] == CYCLES + 1
    undefined = sorted(n for n in template.data_vars
                       if template[n].attrs.get("undefined_when") == "broken")
    assert undefined == sorted(["strain", "stress", "stress_amplitude", "strain_amplitude",
                                "plastic_strain_amplitude", "n_prime", "K_prime"])
    # a monotonic bar always breaks: it asks no question a break answers
    assert "broken" not in solver(loading="monotonic", local_bonds=20).outputs()


STUDY = """\
name = "bar-breaks"
solver = "gamut_bar"
scene = {{ material = "M2", loading = "cyclic", local_bonds = 20, cycles = 3, cycle_repeats = 2, amplitude_range = [1.0, 1.06] }}
{outputs}
[[inputs]]
name = "bar.eps_f"
distribution = "uniform"
lower = 0.002
upper = 0.06

[method]
kind = "monte-carlo"
samples = 16

[execution]
workers = 0
seed = 3
max_failure_fraction = 1.0

[output]
path = "result.nc"
figures = false

[[limit_states]]
name = "broken"
output = "broken"
is = true

[[limit_states]]
name = "by_cycle_4"
output = "break_cycle"
below = 4
"""
STORED = 'outputs = ["broken", "break_cycle", "break_bond", "failure_strain"]\n'


def test_monte_carlo_counts_the_breaks_and_keeps_failed_realizations_apart(tmp_path):
    from uqflow.execute import run_study
    from uqflow.store import open_result

    path = tmp_path / "study.toml"
    path.write_text(STUDY.format(outputs=STORED), encoding="utf-8")
    result = run_study(load_study(path), show_progress=False)
    tree = open_result(result.path)
    runs, stats = tree["runs"].to_dataset(), tree["statistics"].to_dataset()
    eps_f = runs["inputs"].sel(parameter="bar.eps_f").values
    ok = runs["status"].values == "ok"
    broken = ok & (runs["broken"].values == 1)
    # eps_f below the yield strain (0.009494 for M2) is a bad input: failed, with its message
    assert np.array_equal(~ok, eps_f < 0.009494) and (~ok).sum() >= 1
    assert all("bar.eps_f" in m for m in runs["message"].values[~ok])
    # a bar that fails sooner breaks sooner: every broken bar's eps_f is below every
    # survivor's, and both kinds are in the sample (the limit state cuts through it)
    survived = ok & ~broken
    assert broken.sum() >= 1 and survived.sum() >= 1
    assert eps_f[broken].max() < eps_f[survived].min()
    by_cycle_4 = ok & (runs["break_cycle"].values <= 4)
    ls = stats["failures"].to_series()
    assert ls["broken"] == broken.sum() and ls["by_cycle_4"] == by_cycle_4.sum()
    assert stats["failure_probability_runs"].values.tolist() == [ok.sum()] * 2
    assert stats["failure_probability_left_out"].values.tolist() == [(~ok).sum()] * 2
    assert stats["failure_probability"].sel(limit_state="broken").item() == \
        broken.sum() / ok.sum()


def test_a_study_of_breaks_storing_what_a_broken_bar_lacks_is_refused_in_one_line(tmp_path):
    path = tmp_path / "study.toml"
    path.write_text(STUDY.format(outputs=""), encoding="utf-8")
    with pytest.raises(StudyError) as caught:
        load_study(path)
    assert caught.value.key == "outputs" and "'n_prime'" in caught.value.reason
    assert str(caught.value).startswith(f"{path}: outputs: ") and "\n" not in str(caught.value)


def test_a_threshold_past_the_cycles_is_refused_in_one_line(tmp_path):
    path = tmp_path / "study.toml"
    path.write_text(STUDY.format(outputs=STORED).replace("below = 4", "below = 7"),
                    encoding="utf-8")
    with pytest.raises(StudyError) as caught:
        load_study(path)
    assert caught.value.key == "limit_states[1].below"
    assert "is 7 where the event did not happen within the loading" in caught.value.reason


def test_discrete_outputs_round_trip_through_the_result(tmp_path):
    """The limit states a report rebuilds from stored runs see the same declarations."""
    from uqflow.limit_states import LimitStates

    ds = bar().outputs()[["broken", "break_cycle"]]
    path = tmp_path / "t.nc"
    ds.expand_dims(realization=1).to_netcdf(path)
    back = xr.open_dataset(path)
    ls = LimitStates.from_tables([{"name": "b", "output": "broken", "is": True},
                                  {"name": "c", "output": "break_cycle", "below": 3}],
                                 back.isel(realization=0, drop=True))
    assert ls.is_discrete("b") and ls.is_discrete("c")
