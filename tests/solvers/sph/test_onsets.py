"""The applied strain at which debonding starts (issue 18, point 1): the outputs
debonding_onset_strain and detachment_onset_strain against what the per-step debonding
outputs of the same run say, "not within the loading" as the strain one step past it, and a
limit state P[debonding starts below a strain] on them."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from solvers.sph import SPHSolver
from solvers.sph.loading import run_tension
from solvers.sph.solver import onset_strains
from uqflow.errors import StudyError
from uqflow.limit_states import LimitStates

from .test_debonding import SharedLoad, fake_layout

sys.path.insert(0, str(Path(__file__).parent))
from _scenes import example1  # noqa: E402

EPS = float(np.finfo(float).eps)
STEPS = 4


def scene(strength):
    """A 129-particle plate with one circular inclusion of 8 pairs, pulled in 4 steps; at an
    interface strength of 5 Pa pairs break from step 3, at 50 Pa none does (run: 0.3-0.7 s)."""
    return example1("regular", spacing=12.0, loading="tension", step=0.1, steps=STEPS,
                    interface_strength=strength)


@pytest.fixture(scope="module")
def runs():
    """The weak and the strong interface, as a study's runs of the onset outputs."""
    solver = SPHSolver.from_scene(scene(5.0))
    weak, strong = solver.run({}), solver.run({"interface.strength": 50.0})
    return solver, weak, strong


def test_the_onset_is_the_strain_of_the_step_where_the_first_pair_broke(runs):
    _, weak, _ = runs
    pairs = weak.sizes["pair"]
    intact = weak["intact_pairs"].values
    first = int(np.flatnonzero(intact < pairs)[0])          # index of that step
    assert first == 2                                       # step 3 of 4 (the scene's note)
    assert weak["debonding_onset_strain"].item() == weak["strain"].values[first]
    # the pairs' own record agrees: the earliest break step is that step
    steps = weak["pair_break_step"].values
    assert steps[steps > 0].min() == first + 1
    # no inclusion detached: the detachment onset is "not within the loading"
    assert not weak["detached_inclusions"].values.any()
    beyond = weak["detachment_onset_strain"]
    assert beyond.item() == beyond.attrs["not_within_loading"]


def test_not_within_the_loading_is_the_strain_one_step_past_it(runs):
    solver, weak, strong = runs
    assert (strong["intact_pairs"].values == strong.sizes["pair"]).all()
    onset = strong["debonding_onset_strain"].item()
    assert onset == strong["detachment_onset_strain"].item()
    assert onset == solver.outputs()["debonding_onset_strain"].attrs["not_within_loading"]
    # the strain grid is linear, k * 2 step / height: step 5's is 5/4 of step 4's (the two
    # products and the quotient round by 1/2 ulp each: 4 eps bounds the difference)
    last = strong["strain"].values[-1]
    assert onset == pytest.approx(last * (STEPS + 1) / STEPS, rel=4 * EPS)
    assert onset > last
    assert weak["debonding_onset_strain"].attrs["output_values"] == "discrete"


def test_onsets_of_a_history_where_an_inclusion_detaches():
    """The fake problem of test_debonding: inclusion 0's pair 0 breaks at step 2, its other
    three at step 4 (its last pairs: detached); inclusion 1 holds."""
    layout = fake_layout()
    factor = [1.0, 0.3, 0.3, 0.3, 0.1, 0.1, 0.1, 0.1]
    h = run_tension(SharedLoad(layout, factor), layout, strength=1.5, step=1.0, steps=5)
    assert h.pair_break_step.tolist() == [2, 4, 4, 4, 0, 0, 0, 0]
    assert h.inclusion_detach_step.tolist() == [4, 0]
    # strain of step k: 2 k step / height, height 2
    assert onset_strains(h, 6.0) == {"debonding_onset_strain": 2.0,
                                     "detachment_onset_strain": 4.0}
    intact = run_tension(SharedLoad(layout, [0.1] * 8), layout, strength=1.5, step=1.0,
                         steps=5)
    assert onset_strains(intact, 6.0) == {"debonding_onset_strain": 6.0,
                                          "detachment_onset_strain": 6.0}


def test_p_debonding_below_a_strain_is_a_discrete_limit_state(runs):
    solver, weak, strong = runs
    template = solver.outputs()[["debonding_onset_strain"]]
    threshold = 0.5 * (weak["strain"].values[2] + weak["strain"].values[3])
    ls = LimitStates.from_tables([{"name": "early", "output": "debonding_onset_strain",
                                   "below": threshold}], template, "study.toml")
    data = xr.concat([weak[["debonding_onset_strain"]], strong[["debonding_onset_strain"]]],
                     dim="realization")
    data["status"] = ("realization", np.array(["ok", "ok"], dtype=object))
    assert ls.failures(data).values[:, 0].tolist() == [True, False]
    assert ls.is_discrete("early")
    with pytest.raises(StudyError, match="form needs a continuous one"):
        ls.require_continuous("early", "form")
    beyond = template["debonding_onset_strain"].attrs["not_within_loading"]
    with pytest.raises(StudyError) as caught:
        LimitStates.from_tables([{"name": "late", "output": "debonding_onset_strain",
                                  "below": beyond}], template, "study.toml")
    assert caught.value.key == "limit_states[0].below" and "\n" not in str(caught.value)
