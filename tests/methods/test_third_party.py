"""A third party adds a propagation method without touching uqflow."""

import os
import re
import subprocess
import sys
import types
from pathlib import Path

import uqflow
from uqflow.execute import run_study
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


def _method_from_the_docs():
    """The antithetic Monte Carlo method of docs/writing-a-method.md (its first Python block),
    as a module of its own: what a third party writes from that page."""
    page = Path(__file__).resolve().parents[2] / "docs" / "writing-a-method.md"
    code = re.search(r"```python\n(.*?)```", page.read_text(), re.S).group(1)
    module = sys.modules.setdefault("docs_writing_a_method_method",
                                    types.ModuleType("docs_writing_a_method_method"))
    exec(compile(code, str(page), "exec"), module.__dict__)
    return module.Antithetic


Antithetic = _method_from_the_docs()


def test_method_registered_through_the_public_api_runs_a_study(tmp_path):
    path = tmp_path / "study.toml"
    path.write_text(STUDY.format(kind="antithetic"))
    out = run_study(load_study(path), show_progress=False)
    # y = 1 + 2 x1 - x2 is linear: antithetic pairs give its mean exactly.
    exact_mean = 1 + 2 * 1.0 - 3.0
    assert abs(float(out.statistics["y"].sel(statistic="mean")) - exact_mean) < 1e-12
    assert out.runs.sizes["realization"] == 16
    assert "antithetic" in uqflow.methods.method_registry.names()
    assert out.statistics.attrs["pairs_used"] == 8  # the docs' method ran
    assert Antithetic.name == "antithetic"


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
