"""Every built-in solver and method passes uqflow.testing; broken ones fail it, saying why."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import tomllib
import warnings
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

import uqflow
from solvers.analytic import AnalyticSolver
from solvers.gamut_bar import GamutBarSolver
from solvers.mpm import MPMSolver
from solvers.sph import SPHSolver
from uqflow.methods.base import (MethodOptions, PropagationMethod, finish_statistics,
                                 make_design, ok_mask, output_names)
from uqflow.methods.monte_carlo import MonteCarlo
from uqflow.testing import (ConformanceError, ConformanceWarning, NotApplicable, TinyModel,
                            check_method, check_solver, checks)

# The smallest scenes of the solvers' own tests (tests/solvers/*): each run takes milliseconds
# once numba's cache is warm.
MPM_TINY = dict(domain=dict(x=[0.0, 0.1], y=[0.0, 0.1]), cell_size=0.01, particles_per_cell=2,
                materials=dict(m=dict(model="elastic", rho0=1000.0, E=1e6, nu=0.3)),
                bodies=[dict(name="block", material="m", shape="rectangle", min=[0.02, 0.02],
                             max=[0.08, 0.08], velocity=[1.0, 0.0])],
                end_time=0.002, output_interval=0.0005,
                probes=[dict(name="c", point=[0.05, 0.05], body="block")])
# The same block of Johnson-Cook steel with a Mie-Grueneisen EOS pushed against a fixed wall:
# it declares local sensitivities (stresses, pressure and flow stress wrt jc.* and eos.*).
MPM_JC_TINY = dict(MPM_TINY, materials=dict(m=dict(model="steel_4340")),
                   bodies=[dict(MPM_TINY["bodies"][0], velocity=[50.0, 0.0])],
                   boundaries=dict(left="fixed"), end_time=2e-5, output_interval=5e-6)
# A random layout of 3 inclusions, 3 load steps: runs take a seed (the layout's), and a
# finite interface strength (the seed's Example 1 has an infinite one, refused by "nominal").
SPH_TINY = dict(layout="random", width=100e-6, height=100e-6, spacing=5e-6,
                random=dict(count=3, semi_axes_min=[8e-6, 6e-6], semi_axes_max=[12e-6, 8e-6],
                            layout_seed=1),
                matrix=dict(E=1e6, nu=0.4), inclusion=dict(E=150e6, nu=0.3),
                interface_strength=0.04e6, loading="tension", step=0.05e-6, steps=3)
GAMUT_BAR_TINY = {"local_bonds": 10}

def _entry_points() -> dict:
    with open(Path(__file__).resolve().parents[1] / "pyproject.toml", "rb") as fh:
        return tomllib.load(fh)["project"]["entry-points"]


SOLVERS = {
    "analytic-linear": (AnalyticSolver, dict(model="linear", coefficients=[2.0, -1.0])),
    "analytic-exponential-decay": (AnalyticSolver, dict(model="exponential_decay")),
    "analytic-euler-decay": (AnalyticSolver, dict(model="euler_decay")),
    "analytic-random-E-bar": (AnalyticSolver, dict(model="random_E_bar", points=8)),
    "tiny": (TinyModel, {}),
    "mpm": (MPMSolver, MPM_TINY),
    "mpm-johnson-cook": (MPMSolver, MPM_JC_TINY),
    "sph": (SPHSolver, SPH_TINY),
    "gamut_bar": (GamutBarSolver, GAMUT_BAR_TINY),
}


# Every other built-in solver (entry point) with its scene's defaults: one whose scene needs
# keys adds its smallest scene above. The UM-Bridge solver needs a server to talk to: it passes
# check_solver against one in tests/umbridge/test_umbridge_solver.py.
NEEDS_A_SERVER = {"umbridge"}
SOLVERS.update({name: (uqflow.get_solver(name), {}) for name in
                _entry_points()["uqflow.solvers"]
                if name not in {cls.name for cls, _ in SOLVERS.values()} | NEEDS_A_SERVER})


@pytest.mark.parametrize("label", list(SOLVERS))
def test_built_in_solver_passes_check_solver(label):
    cls, scene = SOLVERS[label]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConformanceWarning)  # labels: the solvers' owners
        outcome = check_solver(cls, scene)
    assert set(outcome) >= {"contract", "deterministic", "failure_capture", "pickle",
                            "bad_scene", "run_matches_template"}
    assert all(v == "ok" or v.startswith("not applicable") for v in outcome.values())
    if label in ("mpm-johnson-cook", "tiny") or label.startswith("analytic-") and \
            label != "analytic-random-E-bar":
        assert outcome["local_sensitivities"] == "ok"


#: kind -> (options, keyword arguments of check_method); a few realizations each
METHODS = {
    "monte-carlo": ({"samples": 8}, {"random_plan": True}),
    "taylor": ({}, {}),
    "taylor-local": ({}, {}),
    "sobol": ({"samples": 8}, {"random_plan": True}),
    "nominal": ({}, {}),
    "pce": ({}, {}),
    "kl-weibull": ({"realizations": 6}, {"fields": True, "random_plan": True}),
    # levels: the tiny model's resolution; a pilot of 4 and one allocation round
    "multilevel": ({"target_rel_rmse": 0.05, "pilot": 4, "max_rounds": 1,
                    "costs": [1.0, 4.0]}, {"levels": [4, 16], "random_plan": True}),
    "multifidelity": ({"target_rel_rmse": 0.05, "pilot": 4, "max_rounds": 1,
                       "costs": [1.0, 4.0]}, {"levels": [4, 16], "random_plan": True}),
    # the tiny y is about 5 m with a std near 1 m: a limit state about one std away
    "form": ({}, {"limit_states": [{"name": "high", "output": "y", "exceeds": 6.0}]}),
    "sorm": ({}, {"limit_states": [{"name": "high", "output": "y", "exceeds": 6.0}]}),
    # 40 draws after FORM's search; cross-entropy: rounds of 40 draws (p ~ 0.16 > rho: one)
    "importance-sampling": ({"samples": 40},
                            {"limit_states": [{"name": "high", "output": "y", "exceeds": 6.0}],
                             "random_plan": False}),
    "cross-entropy": ({"samples": 40},
                      {"limit_states": [{"name": "high", "output": "y", "exceeds": 6.0}],
                       "random_plan": True}),
    # 20 samples a level in 5 chains of 4: p ~ 0.2 takes two levels, 4 rounds
    "subset-simulation": ({"samples_per_level": 20, "level_probability": 0.25},
                          {"limit_states": [{"name": "high", "output": "y", "exceeds": 6.0}],
                           "random_plan": True}),
    # levels and a limit state: a cross-entropy round or two of 20 coarse runs, 20 fine runs
    "multifidelity-importance-sampling": (
        {"coarse_samples": 20, "samples": 40, "costs": [1.0, 4.0]},
        {"levels": [4, 16], "random_plan": True,
         "limit_states": [{"name": "high", "output": "y", "exceeds": 6.0}]}),
    # levels and a limit state: 20 samples a subset in 5 chains of 4, 2 burn-in steps
    "multilevel-subset-simulation": (
        {"samples_per_level": 20, "level_probability": 0.25, "burn_in": 2,
         "costs": [1.0, 4.0]},
        {"levels": [4, 16], "random_plan": True,
         "limit_states": [{"name": "high", "output": "y", "exceeds": 6.0}]}),
}


#: every built-in method: the options above where a method needs some, its defaults otherwise,
#: so a new method is checked by its entry point alone
BUILT_IN_METHODS = sorted(_entry_points()["uqflow.methods"])


@pytest.mark.parametrize("kind", BUILT_IN_METHODS)
def test_built_in_method_passes_check_method(kind, tmp_path):
    options, kwargs = METHODS.get(kind, ({}, {}))
    outcome = check_method(uqflow.get_method(kind), options, folder=tmp_path, **kwargs)
    assert outcome == dict.fromkeys(outcome, "ok")


@pytest.mark.parametrize("name, check", list(checks(TinyModel, {})))
def test_checks_one_by_one_for_pytest(name, check):
    check()


def test_a_solver_with_a_random_field_is_deterministic_under_the_same_field():
    from uqflow.fields import FieldSample, FieldSpec, RandomField

    bar = AnalyticSolver.from_scene(dict(model="random_E_bar", points=8))
    field = RandomField(FieldSpec(name="bar.E", correlation_length=0.05, modes=3,
                                  cv=0.05), bar.field_points("bar.E"))
    germs = np.random.default_rng(7).standard_normal(field.n_modes)
    sample = FieldSample([field], {"bar.E": germs})
    assert check_solver(bar, fields=sample)["deterministic"] == "ok"
    nominal = float(bar.run({})["end_displacement"])
    assert float(bar.run({}, sample)["end_displacement"]) != nominal  # the field acts


def test_an_instance_is_checked_without_its_scene_checks():
    outcome = check_solver(TinyModel.from_scene({}))
    assert outcome["bad_scene"].startswith("not applicable: bad_scene: no scene given")
    assert outcome["deterministic"] == "ok"


# ---------------------------------------------------------------- a broken third-party solver

class DriftingSolver(uqflow.Solver):
    """Broken twice: it draws its noise from global state, not from its ``seed`` (two runs
    with one seed differ), and its profile grows a point at every run."""

    def __init__(self):
        self.calls = 0

    @classmethod
    def from_scene(cls, scene):
        return cls()

    def nominal(self):
        return {"load": 1.0}

    def outputs(self):
        return xr.Dataset({"y": xr.Variable((), np.nan, {"units": "m", "long_name": "y"}),
                           "profile": xr.Variable("x", np.full(3, np.nan),
                                                  {"units": "Pa", "long_name": "profile"})})

    def run(self, params, fields=None, seed=None):
        self.calls += 1
        load = float(params.get("load", 1.0))
        noise = np.random.default_rng().normal()  # not from seed: the bug
        n = 3 + self.calls % 2  # the other bug: the dims change between runs
        return xr.Dataset({"y": xr.Variable((), load + noise, {"units": "m"}),
                           "profile": xr.Variable("x", np.full(n, load), {"units": "Pa"})})


def test_a_non_deterministic_solver_fails_saying_so():
    with pytest.raises(ConformanceError) as err:
        check_solver(DriftingSolver, {})
    failures = err.value.failures
    assert failures["deterministic"].startswith(
        "deterministic: two runs with the same parameters and seed=12345 differ: output 'y' "
        "differs at index ()")
    assert "np.random.default_rng(seed)" in failures["deterministic"]


def test_an_output_whose_dims_change_between_runs_fails_naming_output_and_dims():
    with pytest.raises(ConformanceError) as err:
        check_solver(DriftingSolver, {})
    message = err.value.failures["run_matches_template"]
    assert "output 'profile' of run(" in message
    assert "has dims {'x': 4}, the outputs() template has {'x': 3}" in message


def test_a_solver_that_accepts_any_scene_fails_bad_scene():
    with pytest.raises(ConformanceError) as err:
        check_solver(DriftingSolver, {})
    assert err.value.failures["bad_scene"] == (
        "bad_scene: from_scene accepted the scene with a bad scene.no_such_key_for_conformance "
        "(validate every scene key and refuse unknown ones with SceneError)")


class Unitless(TinyModel):
    def outputs(self):
        template = super().outputs()
        del template["y"].attrs["units"]
        return template


def test_a_missing_unit_fails_the_template_check():
    with pytest.raises(ConformanceError) as err:
        check_solver(Unitless, {})
    assert err.value.failures["outputs_template"] == (
        "outputs_template: output 'y' has no 'units' attribute (set attrs['units'] (SI, '1' "
        "when dimensionless) on 'y')")


class Shifted(TinyModel):
    """Its runs put the profile at other positions than its template says."""

    def run(self, params, fields=None):
        return super().run(params, fields).assign_coords(s=self.S + 1.0)


def test_a_run_on_other_coordinates_than_the_template_fails():
    with pytest.raises(ConformanceError) as err:
        check_solver(Shifted, {})
    assert err.value.failures["run_matches_template"].startswith(
        "run_matches_template: coordinate 's' of output 'profile' in run(nominal parameters) "
        "differs (the template's: [0. 1. 2.]...)")


class Unlabelled(TinyModel):
    def outputs(self):
        template = super().outputs()
        del template["profile"].attrs["long_name"]
        return template


def test_a_missing_long_name_is_a_warning_naming_the_outputs():
    with pytest.warns(ConformanceWarning, match="no 'long_name' on profile: "):
        check_solver(Unlabelled, {})


class Exits(TinyModel):
    def run(self, params, fields=None):
        if any(np.isnan(v) for v in params.values()):
            raise SystemExit("gave up")
        return super().run(params, fields)


def test_a_solver_whose_failure_escapes_as_base_exception_fails():
    with pytest.raises(ConformanceError) as err:
        check_solver(Exits, {})
    assert err.value.failures["failure_capture"].startswith(
        "failure_capture: SystemExit escaped uqflow's runner")


# ---------------------------------------------------------------- a broken third-party method

class ClockSeeded(MonteCarlo):
    """Broken: its design ignores the seed (drawn from fresh OS entropy at every plan)."""

    def plan(self, space, fields, seed):
        return super().plan(space, fields, np.random.SeedSequence())


class FlatOptions(MethodOptions):
    samples: int = 8


class DimDropping(PropagationMethod):
    """Broken: analyze averages every output over all its dims (the profile loses 's')."""

    Options = FlatOptions

    def plan(self, space, fields, seed):
        u = np.random.default_rng(seed).random((self.options.samples, len(space)))
        return make_design(space, space.from_unit_hypercube(u))

    def analyze(self, design, runs):
        ok = ok_mask(runs)
        data = {o: (("statistic",), [float(np.mean(runs[o].values[ok]))])
                for o in output_names(runs)}
        return finish_statistics(xr.Dataset(data, coords={"statistic": ["mean"]}), design,
                                 runs, self.name, [])


def test_a_plan_that_ignores_its_seed_fails_saying_so(tmp_path):
    with pytest.raises(ConformanceError) as err:
        check_method(ClockSeeded, {"samples": 4}, folder=tmp_path)
    assert err.value.failures["plan_deterministic"] == (
        "plan_deterministic: two plans with the same SeedSequence differ in inputs (draw every "
        "random number from the seed argument (np.random.default_rng(seed)), never from global "
        "state or the clock)")


def test_an_analyze_that_drops_a_dim_fails_naming_output_and_dim(tmp_path):
    with pytest.raises(ConformanceError) as err:
        check_method(DimDropping, {"samples": 4}, folder=tmp_path)
    assert set(err.value.failures) == {"analyze"}
    assert err.value.failures["analyze"] == (
        "analyze: analyze dropped the dim(s) 's' of output 'profile' (its statistics have "
        "dims ('statistic',)) (keep every dim of an output in its statistics, e.g. reduce "
        "over 'realization' only)")


class Lax(DimDropping):
    def __init__(self, **options):
        options.pop("no_such_option", None)  # swallows what it does not know
        super().__init__(**options)


def test_a_method_with_a_lax_option_fails_strict_options(tmp_path):
    with pytest.raises(ConformanceError) as err:
        check_method(Lax, {"samples": 4}, folder=tmp_path)
    assert err.value.failures["strict_options"] == (
        "strict_options: the method accepted the bad option {'no_such_option': 1} (declare "
        "every option in Options (extra keys are refused))")


def test_a_check_that_does_not_apply_is_a_skip():
    found = dict(checks(GamutBarSolver, GAMUT_BAR_TINY))
    with pytest.raises(NotApplicable, match="declares none"):
        found["local_sensitivities"]()


# ---------------------------------------------------------------- solver_from_function

def _tip(F=1000.0, L=2.0):
    """Tip deflection-like product and a line over three stations."""
    return {"d": F * L**3, "line": F * np.array([0.0, 0.5, 1.0]) * L}


Tip = uqflow.solver_from_function(_tip, outputs={"d": (), "line": ("station",)},
                                  units={"d": "m", "line": "m"},
                                  coords={"station": [0.0, 0.5, 1.0]}, name="tip")


def test_a_function_solver_passes_check_solver_and_runs_its_function():
    assert check_solver(Tip, {"L": 3.0})["bad_scene"] == "ok"
    result = Tip.from_scene({"L": 3.0}).run({"F": 2.0})
    assert float(result["d"]) == 2.0 * 27.0  # exact in binary: small integers
    assert result["line"].values.tolist() == [0.0, 3.0, 6.0]
    assert result["line"].attrs == {"units": "m", "long_name": "line"}


def test_a_function_solver_pickles_to_the_same_class():
    import pickle

    copy = pickle.loads(pickle.dumps(Tip.from_scene({"F": 5.0})))
    assert type(copy) is Tip and copy.nominal() == {"F": 5.0, "L": 2.0}


def _half_done(F=1.0):
    """Forgets an output for F > 0, returns it on a wrong grid for F <= 0."""
    return {"d": F} if F > 0 else {"d": F, "line": [1.0, 2.0]}


HalfDone = uqflow.solver_from_function(_half_done, outputs={"d": (), "line": ("station",)},
                                       units={"d": "m", "line": "m"},
                                       coords={"station": [0.0, 0.5, 1.0]})


@pytest.mark.parametrize("force, message", [
    (1.0, "_half_done returned no output 'line'"),
    (-1.0, "_half_done returned output 'line' of shape (2,); its dims ('station',) have "
           "shape (3,)"),
])
def test_a_function_solver_says_which_output_is_wrong(force, message):
    with pytest.raises(uqflow.SolverError, match=re.escape(message)):
        HalfDone.from_scene({}).run({"F": force})


@pytest.mark.parametrize("kwargs, error", [
    (dict(outputs="d", units={}), "output 'd' has no units"),
    (dict(outputs=["d", "e"], units="m"), "give units as {output: units}"),
    (dict(outputs={"d": ("x",)}, units="m"), "dim 'x' of output 'd' has no coordinate"),
    (dict(outputs="d", units="m", parameters={"a b": 1.0}), "'a b' is not a dotted name"),
    (dict(outputs="d", units="m", parameters={"G": 1.0}), "_tip takes no argument 'G'"),
])
def test_a_function_solver_made_wrong_is_refused_when_made(kwargs, error):
    with pytest.raises((TypeError, ValueError), match=re.escape(error)):
        uqflow.solver_from_function(_tip, **kwargs)


def test_a_function_without_defaults_needs_parameters():
    with pytest.raises(TypeError, match="parameter 'x' of f has no numeric default"):
        def f(x):
            return x
        uqflow.solver_from_function(f, outputs="y", units="m")


PLUGIN = '''
import uqflow


def beam(F=1000.0, L=2.0):
    return F * L


Beam = uqflow.solver_from_function(beam, outputs="moment", units="N m", name="beam-fn")
'''

BEAM_STUDY = """\
name = "beam"
solver = "beam-fn"
scene = { L = 3.0 }

[[inputs]]
name = "F"
distribution = "uniform"
lower = 900.0
upper = 1100.0

[method]
kind = "taylor"

[execution]
workers = 0

[output]
path = "out/beam.nc"
figures = false
"""


def test_a_function_solver_from_an_entry_point_runs_a_study(tmp_path, monkeypatch):
    from uqflow.solver import solver_registry

    # A package with a dist-info folder on sys.path is what pip leaves behind: the registry
    # finds its entry point as a pip-installed plug-in's (here in this process, the
    # registry's state restored after the test).
    site = tmp_path / "site"
    site.mkdir()
    (site / "beamplug.py").write_text(PLUGIN)
    info = site / "beamplug-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: beamplug\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[uqflow.solvers]\nbeam-fn = beamplug:Beam\n")
    (tmp_path / "beam.toml").write_text(BEAM_STUDY)
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setattr(solver_registry, "_classes", dict(solver_registry._classes))
    monkeypatch.setattr(solver_registry, "_entry_points_loaded", False)
    monkeypatch.delitem(sys.modules, "beamplug", raising=False)
    outcome = uqflow.run_study(uqflow.load_study(tmp_path / "beam.toml"), show_progress=False)
    assert uqflow.get_solver("beam-fn").__module__ == "beamplug"
    # moment = 3 F is linear: Taylor's mean is exact, 3 × 1000 (binary-exact integers)
    assert float(outcome.statistics["moment"].sel(statistic="mean")) == 3000.0


def test_a_built_in_name_imports_its_own_module_and_no_other_built_in():
    # a fresh process: what a CLI run or a dask worker imports to find its solver and method
    code = ("import sys; import uqflow; uqflow.get_solver('analytic'); "
            "from uqflow.registry import method_registry as m; m.get('monte-carlo'); "
            "print(sorted(k for k in sys.modules if k.split('.')[0] == 'solvers' "
            "or k.startswith('uqflow.methods.')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=Path(__file__).parents[1]).stdout
    imported = ast.literal_eval(out)
    assert "solvers.analytic" in imported and "uqflow.methods.monte_carlo" in imported
    assert not [m for m in imported if m.startswith(("solvers.mpm", "solvers.sph",
                                                     "uqflow.methods.form"))]


def test_a_name_that_is_no_module_is_still_found_among_the_built_ins(monkeypatch):
    from uqflow.registry import method_registry

    monkeypatch.setattr(method_registry, "_classes", {})
    monkeypatch.setattr(method_registry, "_entry_points_loaded", False)
    # "sorm" lives in form.py, "cross-entropy" in importance_sampling.py
    assert method_registry.get("sorm").name == "sorm"
    assert method_registry.get("cross-entropy").name == "cross-entropy"
