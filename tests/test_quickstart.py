"""The quickstart answers what README.md says it answers: the scatter of the thin plate's
stresses, how sure (the control variate's correlation and reduction) and what it cost."""

from pathlib import Path

import numpy as np
import pytest

from uqflow import report
from uqflow.execute import run_study
from uqflow.study import load_study

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def quickstart(tmp_path_factory):
    study = load_study(ROOT / "studies" / "quickstart.toml")
    out = run_study(study, workers=0, show_progress=False,
                    output=tmp_path_factory.mktemp("quickstart") / "quickstart.nc")
    return report.open_result(out.path)


def _at_largest_std(stats, name):
    """The (time, probe) point the summary table reports: the output's largest std."""
    std = stats[name].sel(statistic="std")
    return np.unravel_index(int(np.nanargmax(std.values)), std.shape)


@pytest.mark.slow
def test_the_control_run_and_the_samples_all_succeed(quickstart):
    stats = quickstart["statistics"].to_dataset()
    assert (stats.attrs["solver_runs"], stats.attrs["failed_runs"]) == (9, 0)


@pytest.mark.slow
def test_the_flow_stress_follows_its_taylor_polynomial(quickstart):
    """README: "For the flow stress rho > 0.99"; S11 and S22 follow it less."""
    stats = quickstart["statistics"].to_dataset()
    rho = {o: float(stats[f"{o}_correlation"].values[_at_largest_std(stats, o)])
           for o in ("flow_stress", "S11", "S22")}
    assert rho["flow_stress"] > 0.99, rho
    assert max(abs(rho["S11"]), abs(rho["S22"])) < rho["flow_stress"], rho


@pytest.mark.slow
def test_the_table_says_what_the_answer_cost_and_how_sure_it_is(quickstart):
    text = report.summary_table(quickstart)
    assert "95 % CI of the mean" in text
    assert "control variate taylor-local" in text and "equivalent to" in text
    assert "cost: 9 solver runs, 0 failed" in text
    comparison, _ = report.solver_report([quickstart], Path("."), figures=False)
    assert "rows 'seed': seed 000's Table 6" in comparison and "speed-up" in comparison
    # the one-run answer beside the corrected one, for every probe of every output
    assert comparison.count("its control: taylor-local surrogate") == 3 * 4
