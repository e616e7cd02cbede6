"""A third party adds a propagation method without touching uqflow."""

import os
import subprocess
import sys

import numpy as np
import xarray as xr

import uqflow
from uqflow.execute import run_study
from uqflow.methods.base import (MethodOptions, PropagationMethod, finish_statistics,
                                 make_design, ok_mask, output_names)
from uqflow.study import load_study

STUDY = """\
name = "antithetic"
solver = "analytic"
scene = {{ model = "linear", coefficients = [2.0, -1.0], offset = 1.0 }}

[[inputs]]
name = "x1"
distribution = "normal"
mean = 1.0
std = 0.5

[[inputs]]
name = "x2"
distribution = "normal"
mean = 3.0
std = 2.0

[method]
kind = "{kind}"
pairs = 8

[execution]
workers = 0

[output]
path = "out/{kind}.nc"
figures = false
"""


class AntitheticOptions(MethodOptions):
    pairs: int = 16


@uqflow.register_method("antithetic-test")
class Antithetic(PropagationMethod):
    """Antithetic Monte Carlo: every point u comes with 1 - u."""

    Options = AntitheticOptions

    def plan(self, space, fields, seed):
        u = np.random.default_rng(seed).random((self.options.pairs, len(space)))
        return make_design(space, space.from_unit_hypercube(np.vstack([u, 1 - u])))

    def analyze(self, design, runs):
        ok = ok_mask(runs)
        data = {}
        for out in output_names(runs):
            y = runs[out].values[ok]
            data[out] = (("statistic",), [y.mean(), y.var(ddof=1)])
        stats = xr.Dataset(data, coords={"statistic": ["mean", "variance"]})
        return finish_statistics(stats, design, runs, self.name, [])


def test_method_registered_through_the_public_api_runs_a_study(tmp_path):
    path = tmp_path / "study.toml"
    path.write_text(STUDY.format(kind="antithetic-test"))
    out = run_study(load_study(path), show_progress=False)
    # y = 1 + 2 x1 - x2 is linear: antithetic pairs give its mean exactly.
    exact_mean = 1 + 2 * 1.0 - 3.0
    assert abs(float(out.statistics["y"].sel(statistic="mean")) - exact_mean) < 1e-12
    assert out.runs.sizes["realization"] == 16
    assert "antithetic-test" in uqflow.methods.method_registry.names()


PLUGIN = '''
import numpy as np
import xarray as xr
from uqflow.methods.base import (MethodOptions, PropagationMethod, finish_statistics,
                                 make_design, ok_mask, output_names)


class Options(MethodOptions):
    pairs: int = 4


class MeanAtCentre(PropagationMethod):
    """Evaluates the model at the inputs' means only (a plug-in for the entry-point test)."""

    Options = Options

    def plan(self, space, fields, seed):
        return make_design(space, np.tile(space.means, (self.options.pairs, 1)))

    def analyze(self, design, runs):
        ok = ok_mask(runs)
        data = {o: (("statistic",), [runs[o].values[ok].mean()]) for o in output_names(runs)}
        stats = xr.Dataset(data, coords={"statistic": ["mean"]})
        return finish_statistics(stats, design, runs, self.name, [])
'''


def test_method_from_an_entry_point_of_an_installed_package(tmp_path):
    # A package on sys.path with a dist-info folder is what pip leaves behind; importlib.metadata
    # finds its entry points exactly as for a pip-installed plug-in.
    site = tmp_path / "site"
    (site / "uqplugin").mkdir(parents=True)
    (site / "uqplugin" / "__init__.py").write_text(PLUGIN)
    info = site / "uqplugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: uqplugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(
        "[uqflow.methods]\nmean-at-centre = uqplugin:MeanAtCentre\n")
    study = tmp_path / "study.toml"
    study.write_text(STUDY.format(kind="mean-at-centre").replace("pairs = 8", "pairs = 3"))
    env = dict(os.environ, PYTHONPATH=str(site))
    listing = subprocess.run([sys.executable, "-m", "uqflow.cli", "list"], env=env,
                             capture_output=True, text=True, timeout=120)
    assert "mean-at-centre" in listing.stdout
    run = subprocess.run([sys.executable, "-m", "uqflow.cli", "run", str(study), "--quiet"],
                         env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    tree = uqflow.open_result(tmp_path / "out" / "mean-at-centre.nc")
    assert tree["runs"].sizes["realization"] == 3
    assert float(tree["statistics"]["y"].sel(statistic="mean")) == 0.0
    assert tree.attrs["method"] == "mean-at-centre"
