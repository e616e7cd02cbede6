"""Study files with [levels] and the multilevel/multifidelity/Taylor options: what validates
can run, and an error names the key the user wrote and why (uqflow.load_study on small TOML)."""

import numpy as np
import pytest
import xarray as xr

import uqflow
from levels_study import euler_levels_study
from solvers.analytic import AnalyticSolver
from uqflow.errors import StudyError
from uqflow.execute import run_study
from uqflow.solver import solver_registry

def study(tmp_path, *, solver="analytic", scene_extra="", outputs='["y"]', key="steps",
          values="[4, 8, 16]", kind="multilevel", method_extra="costs = [4.0, 8.0, 16.0]"):
    path = tmp_path / "study.toml"
    path.write_text(euler_levels_study("levels-errors", solver=solver, scene_extra=scene_extra,
                                       outputs=outputs, key=key, values=values,
                                       align="interpolate", kind=kind, target_rmse=0.01,
                                       method_extra=method_extra))
    return path


def refused(path) -> StudyError:
    with pytest.raises(StudyError) as info:
        uqflow.load_study(path)
    assert "\n" not in str(info.value)            # one line
    assert str(path) in str(info.value)           # naming the file
    return info.value


# --- the levels' own keys ------------------------------------------------------------------

def test_a_bad_finest_level_value_is_the_levels_values_fault(tmp_path):
    err = refused(study(tmp_path, values="[4, 8, 0]"))
    assert err.key == "levels.values"
    assert "steps = 0 (level 2) gives a bad scene: scene.steps: must be an integer" in err.reason


@pytest.mark.parametrize("key", ["stepz", "random.count"])
def test_an_unknown_levels_key_is_the_levels_key_fault(tmp_path, key):
    err = refused(study(tmp_path, key=key))
    assert err.key == "levels.key"
    assert f"'{key}' is not a key of this scene: unknown key" in err.reason


def test_a_scene_wrong_by_itself_stays_the_scenes_fault(tmp_path):
    # the levels set 'steps'; a typo elsewhere in the scene is not theirs to answer for
    err = refused(study(tmp_path, scene_extra=", tme = 1.0"))
    assert err.key == "scene.tme"
    assert "unknown key" in err.reason


# --- the fidelity methods' options ---------------------------------------------------------

@pytest.mark.parametrize("kind", ["multilevel", "multifidelity"])
def test_a_cost_not_above_zero_is_the_costs_fault(tmp_path, kind):
    err = refused(study(tmp_path, kind=kind, method_extra="costs = [4.0, 0.0, 16.0]"))
    assert err.key == "method.costs"
    assert "every cost must be > 0, got 0.0" in err.reason


def test_the_surrogate_refused_for_correlated_non_normal_inputs_is_the_surrogates_fault(
        tmp_path):
    path = tmp_path / "mfmc.toml"
    path.write_text('name = "s"\nsolver = "analytic"\nscene = { model = "ishigami" }\n'
                    + "".join(f'\n[[inputs]]\nname = "x{i}"\ndistribution = "uniform"\n'
                              f'lower = -3.0\nupper = 3.0\n' for i in (1, 2, 3))
                    + '\n[correlation]\ninputs = ["x1", "x2"]\nmatrix = [[1.0, 0.5], '
                      '[0.5, 1.0]]\n\n[levels]\nkey = "a"\nvalues = [6.0, 7.0]\n\n'
                      '[method]\nkind = "multifidelity"\ntarget_rel_rmse = 0.01\n'
                      'surrogate = "taylor-local"\n')
    err = refused(path)
    assert err.key == "method.surrogate"
    assert "surrogate = \"none\"" in err.reason and "control" not in err.reason


def test_allocate_at_needs_a_value(tmp_path):
    err = refused(study(tmp_path, outputs='["path"]',
                        method_extra="allocate_at = { t = [] }\ncosts = [4.0, 8.0, 16.0]"))
    assert err.key == "method.allocate_at.t"
    assert "give at least one 't' value" in err.reason


def test_a_name_for_a_numeric_coordinate_is_refused_with_its_range(tmp_path):
    err = refused(study(tmp_path, outputs='["path"]',
                        method_extra='allocate_at = { t = ["0.0"] }\ncosts = [4.0, 8.0, 16.0]'))
    assert err.key == "method.allocate_at.t"
    assert "'t' coordinates are numbers (17 values from 0 to 1 s), got the string '0.0'" \
        in err.reason


# --- a solver with named probes and a diagnostic timing output -----------------------------

class ProbedDecay(AnalyticSolver):
    """euler_decay's y(T) at two named probes (H: y, I: 2y) and a timing of the run, marked
    a diagnostic (``output_kind``): the layout of the MPM's probes and step timings."""

    PROBES = ["H", "I"]

    def outputs(self):
        return xr.Dataset({"y_at": (("probe",), np.full(2, np.nan), {"units": "1"}),
                           "run_seconds": ((), np.nan, {"units": "s",
                                                        "output_kind": "diagnostic"})},
                          coords={"probe": self.PROBES})

    def run(self, params, fields=None):
        y = float(super().run(params, fields)["y"])
        out = self.outputs()
        out["y_at"].values[:] = [y, 2.0 * y]
        # a timing grows with the level's steps and varies from run to run
        out["run_seconds"].values[()] = 1e-6 * self.model.steps * (1 + params["k"])
        return out


@pytest.fixture
def probed(monkeypatch):
    monkeypatch.setitem(solver_registry._classes, "probed_decay", ProbedDecay)
    return "probed_decay"


def test_a_number_for_named_probes_is_refused_at_load_naming_the_probes(tmp_path, probed):
    # was: validated, then "could not convert string to float: np.str_('H')" in the run
    err = refused(study(tmp_path, solver=probed, outputs='["y_at"]',
                        method_extra="allocate_at = { probe = [0.5] }"))
    assert err.key == "method.allocate_at.probe"
    assert "'probe' coordinates are names (H, I), got the number 0.5" in err.reason
    named = study(tmp_path, solver=probed, outputs='["y_at"]',
                  method_extra='allocate_at = { probe = ["I"] }')
    assert uqflow.load_study(named).method.options.allocate_at == {"probe": ["I"]}


def test_target_rmse_with_one_uncertain_output_needs_no_allocate_on(tmp_path, probed):
    # docs/study-files.md: target_rmse needs exactly one allocating output, the study's only
    # one or one in allocate_on; a diagnostic (a timing) is never an allocating output
    one = study(tmp_path, solver=probed, outputs='["y_at", "run_seconds"]')
    assert uqflow.load_study(one).outputs == ["y_at", "run_seconds"]
    two = study(tmp_path, outputs='["y", "path"]')
    err = refused(two)
    assert err.key == "method.target_rmse"
    assert "2 allocate (y, path)" in err.reason


def test_a_diagnostic_is_refused_as_an_allocating_output(tmp_path, probed):
    err = refused(study(tmp_path, solver=probed, outputs='["y_at", "run_seconds"]',
                        method_extra='allocate_on = ["run_seconds"]'))
    assert err.key == "method.allocate_on"
    assert "'run_seconds' is a diagnostic of the run" in err.reason


def test_a_diagnostic_never_drives_the_default_allocation(tmp_path, probed):
    # the timing's corrections are as large as its values (it grows with the steps), so
    # allocating on it asked for many more samples than y_at needs
    def counts(outputs):
        path = study(tmp_path, solver=probed, outputs=outputs,
                     method_extra="costs = [4.0, 8.0, 16.0]").read_text()
        path = path.replace("target_rmse = 0.01", "target_rel_rmse = 0.01")
        (tmp_path / "rel.toml").write_text(path + '\n[execution]\nworkers = 0\nseed = 2\n'
                                           '\n[output]\npath = "rel.nc"\nfigures = false\n')
        (tmp_path / "rel.nc").unlink(missing_ok=True)
        outcome = run_study(uqflow.load_study(tmp_path / "rel.toml"), show_progress=False)
        return outcome.statistics["level_samples"].values.tolist()

    assert counts('["y_at", "run_seconds"]') == counts('["y_at"]')


# --- float options that validated and then failed every run --------------------------------

TAYLOR = """\
name = "taylor-bounds"
solver = "analytic"
scene = {{ model = "euler_decay" }}

[[inputs]]
name = "k"
distribution = "normal"
mean = 1.0
cv = 0.1

[method]
{method}
"""


@pytest.mark.parametrize("method, key, reason", [
    ('kind = "taylor"\nstep = 1e308', "method.step", "must be <= 1 (a fraction of each "
                                                     "input's std"),
    ('kind = "taylor"\nstep = 1.5', "method.step", "got 1.5"),
    ('kind = "taylor"\nstep_tolerance = 2.0', "method.step_tolerance", "must be < 2"),
    ('kind = "monte-carlo"\nsamples = 8\ncontrol = "taylor"\ncontrol_step = 5.0',
     "method.control_step", "less than or equal to 1"),
])
def test_taylor_steps_beyond_a_std_are_refused(tmp_path, method, key, reason):
    path = tmp_path / "taylor.toml"
    path.write_text(TAYLOR.format(method=method))
    err = refused(path)
    assert err.key == key and reason in err.reason


def test_a_taylor_step_of_one_std_is_accepted(tmp_path):
    path = tmp_path / "taylor.toml"
    path.write_text(TAYLOR.format(method='kind = "taylor"\nstep = 1.0\nstep_tolerance = 1.9'))
    assert uqflow.load_study(path).method.options.step == 1.0
