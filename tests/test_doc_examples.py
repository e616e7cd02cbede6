"""Every ```toml block in README.md and docs/*.md validates and every ```python block runs,
so the examples cannot rot (the Python blocks: see "python blocks" below).

How a block is read (its first line may carry a marker):

- ``# invalid: <why>``: an example of an error; it must FAIL validation (StudyError or
  SceneError), whatever kind of block it is.
- ``# file: <path>``: the content of a file. A scene file (any other name than
  ``pyproject.toml``) is validated as a scene and written at ``<path>`` beside the studies of
  the same page that come after it; ``pyproject.toml`` is only parsed; a study file is
  validated as a study, unless its method is one a ```python block of the page registers and
  that block loads the file: that block's test then loads and runs it.
- a whole study (``solver`` and ``method``): written to a temporary folder that holds the
  project's ``studies/scenes`` as ``scenes/`` (what the shipped studies name) plus the page's
  ``# file:`` blocks, and loaded with ``uqflow.study.load_study``;
- a fragment (only study keys, e.g. ``[method]`` or ``[[inputs]]``): merged into a minimal
  valid study of the solver its parameters belong to, then loaded the same way (inputs whose
  names no solver has — a page about distributions — are renamed x1, x2, ... for the linear
  analytic model, so their distributions and correlations are still checked);
- anything else is a scene: validated with the ``from_scene`` of the solver its keys name.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from test_shipped_studies import to_toml
from uqflow.cli import main
from uqflow.errors import SceneError, StudyError
from uqflow.solver import get_solver
from uqflow.study import StudySpec, load_study

ROOT = Path(__file__).resolve().parent.parent
#: pages whose blocks build on each other, like a notebook's cells: tests/test_extension_docs.py
#: runs their Python blocks in order in one namespace and loads their study files
SEQUENTIAL_PAGES = {"writing-a-solver.md", "writing-a-method.md"}
PAGES = [ROOT / "README.md"] + sorted(p for p in (ROOT / "docs").glob("*.md")
                                      if p.name not in SEQUENTIAL_PAGES)
SCENES = ROOT / "studies" / "scenes"
MPM_SCENE = "scenes/mpm_contact_thin_small.toml"
BLOCK = re.compile(r"^```toml[ \t]*\n(.*?)^```", re.S | re.M)
STUDY_KEYS = set(StudySpec.model_fields)


@dataclass
class Block:
    page: Path
    line: int
    text: str

    @property
    def marker(self) -> tuple[str, str]:
        first = self.text.lstrip().splitlines()[0] if self.text.strip() else ""
        match = re.match(r"#\s*(invalid|file):\s*(\S.*)", first)
        return (match.group(1), match.group(2).strip()) if match else ("", "")

    @property
    def id(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def blocks() -> list[Block]:
    out = []
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for match in BLOCK.finditer(text):
            out.append(Block(page, text.count("\n", 0, match.start()) + 1, match.group(1)))
    return out


BLOCKS = blocks()


# ----------------------------------------------------------------------------- solvers
def _mpm_scene() -> dict:
    with open(SCENES.parent / MPM_SCENE, "rb") as fh:
        return tomllib.load(fh)


def scene_solver(scene: dict) -> str:
    """The solver whose scene keys these are."""
    if "model" in scene:
        return "analytic"
    if {"domain", "bodies", "cell_size", "snapshots"} & set(scene):
        return "mpm"
    return "gamut_bar"


def _parameters(solver: str, scene) -> set[str]:
    if isinstance(scene, str):
        with open(SCENES.parent / scene, "rb") as fh:
            scene = tomllib.load(fh)
    return set(get_solver(solver).from_scene(scene).nominal())


BASES = {
    "analytic": {"scene": {"model": "ishigami", "a": 7.0, "b": 0.1},
                 "inputs": [{"name": f"x{i}", "distribution": "uniform",
                             "lower": -3.141592653589793, "upper": 3.141592653589793}
                            for i in (1, 2, 3)],
                 "method": {"kind": "monte-carlo", "samples": 64}},
    "gamut_bar": {"scene": {"material": "M1", "local_bonds": 50},
                  "method": {"kind": "nominal"}},
    "mpm": {"scene": MPM_SCENE,
            "inputs": [{"name": "steel.jc.A", "distribution": "normal", "mean": 792e6,
                        "cv": 0.1},
                       {"name": "steel.jc.B", "distribution": "normal", "mean": 510e6,
                        "cv": 0.1}],
            "method": {"kind": "taylor", "order": 1}},
}


def _fragment_solver(data: dict) -> str:
    if "solver" in data:
        return data["solver"]
    if isinstance(data.get("scene"), dict):
        return scene_solver(data["scene"])
    if isinstance(data.get("scene"), str):
        with open(SCENES.parent / data["scene"], "rb") as fh:
            return scene_solver(tomllib.load(fh))
    names = {i.get("name") for i in data.get("inputs", [])}
    names |= set(data.get("correlation", {}).get("inputs", []))
    for f in data.get("fields", []):
        names |= set(f.get("parameters", [f.get("name")]))
    if not names:
        return "analytic"
    for solver in ("analytic", "gamut_bar", "mpm"):
        if names <= _parameters(solver, BASES[solver]["scene"]):
            return solver
    return "linear"          # names no solver has: renamed for the linear analytic model


def merged(data: dict) -> dict:
    """A minimal valid study of the fragment's solver with the fragment's tables in it."""
    solver = _fragment_solver(data)
    if solver == "linear":
        rename = {}
        for i in data.get("inputs", []):
            rename[i["name"]] = f"x{len(rename) + 1}"
        data = dict(data, inputs=[dict(i, name=rename[i["name"]]) for i in data["inputs"]])
        if "correlation" in data:
            data["correlation"] = dict(data["correlation"], inputs=[
                rename[n] for n in data["correlation"]["inputs"]])
        study = {"scene": {"model": "linear", "coefficients": [1.0] * len(rename)},
                 "method": {"kind": "monte-carlo", "samples": 64}}
        solver = "analytic"
    else:
        study = dict(BASES[solver])
    study = {"name": "doc-example", "solver": solver, **study}
    if "inputs" in data or "fields" in data:
        study.pop("inputs", None)        # the fragment's own uncertain parameters
    elif "scene" in data and solver == "analytic":
        # another model: one input per parameter of that model
        study["inputs"] = [{"name": n, "distribution": "normal", "mean": v, "std": 1.0}
                           for n, v in get_solver(solver).from_scene(data["scene"])
                           .nominal().items()]
    if isinstance(data.get("scene"), dict) and isinstance(study["scene"], str):
        data = dict(data, scene={**_mpm_scene(), **data["scene"]})
    study.update(data)
    if study["method"]["kind"] == "kl-weibull" and not study.get("fields"):
        study["method"] = BASES[solver]["method"] if solver != "analytic" else \
            {"kind": "monte-carlo", "samples": 64}
    return study


# ----------------------------------------------------------------------------- validation
def _folder(tmp: Path, block: Block) -> Path:
    (tmp / "scenes").mkdir()
    for scene in SCENES.glob("*.toml"):
        (tmp / "scenes" / scene.name).write_bytes(scene.read_bytes())
    for earlier in BLOCKS:               # the page's scene files, as the page shows them
        kind, name = earlier.marker
        if earlier.page == block.page and earlier.line < block.line and kind == "file" \
                and name != "pyproject.toml":
            (tmp / name).parent.mkdir(parents=True, exist_ok=True)
            (tmp / name).write_text(earlier.text, encoding="utf-8")
    return tmp


def _registered_by_page(block: Block, kind) -> bool:
    """Whether a Python block of ``block``'s page registers method ``kind`` and loads the
    file ``block`` is (its study can only load where that method is registered)."""
    name = block.marker[1]
    return any(b.page == block.page and f'register_method("{kind}")' in b.text
               and name in b.text for b in python_blocks() if b.marker[0] != "fragment")


def validate(block: Block, tmp: Path, monkeypatch) -> None:
    """Raise StudyError/SceneError (or a TOML error) if the block does not validate."""
    monkeypatch.chdir(tmp)               # a scene's relative directories land in tmp
    kind, name = block.marker
    data = tomllib.loads(block.text)
    if kind == "file" and name == "pyproject.toml":
        return
    is_study = "solver" in data and "method" in data
    if kind == "file" and is_study and _registered_by_page(block, data["method"].get("kind")):
        return        # a study of the page's own method: loaded and run by the block that
        #               registers the method (test_doc_python_block_runs)
    if (kind == "file" and not is_study) or not set(data) <= STUDY_KEYS:
        get_solver(scene_solver(data)).from_scene(data)
        return
    folder = _folder(tmp, block)
    study = folder / "study.toml"
    if is_study:
        study.write_text(block.text, encoding="utf-8")
    else:
        study.write_text(to_toml(merged(data)) + "\n", encoding="utf-8")
    load_study(study)


def test_the_pages_have_toml_examples():
    assert len(BLOCKS) >= 20
    assert {b.page.name for b in BLOCKS} >= {"README.md", "study-files.md", "fields.md"}


@pytest.mark.parametrize("block", BLOCKS, ids=[b.id for b in BLOCKS])
def test_doc_toml_block_validates(block, tmp_path, monkeypatch):
    if block.marker[0] == "invalid":
        with pytest.raises((StudyError, SceneError, tomllib.TOMLDecodeError)):
            validate(block, tmp_path, monkeypatch)
    else:
        validate(block, tmp_path, monkeypatch)


def test_an_invalid_block_must_fail(tmp_path, monkeypatch):
    """The check itself can fail: a copy of a valid block with a wrong option is caught."""
    good = next(b for b in BLOCKS if b.page.name == "sobol.md")
    bad = Block(good.page, good.line, good.text.replace("samples = 1024", "samples = -3"))
    assert bad.text != good.text
    for name in ("good", "bad"):
        (tmp_path / name).mkdir()
    validate(good, tmp_path / "good", monkeypatch)
    with pytest.raises(StudyError):
        validate(bad, tmp_path / "bad", monkeypatch)


# ----------------------------------------------------------------------------- method options
METHODS_PAGE = ROOT / "docs" / "study-files.md"
SECTION = re.compile(r'^### `kind = "([a-z-]+)"`[^\n]*\n(.*?)(?=^##)', re.S | re.M)
ROW = re.compile(r"^\| `([a-z_0-9]+)` \| ([^|]+) \|", re.M)


def documented_options() -> dict[str, dict[str, str]]:
    """Per method kind in docs/study-files.md: option -> default as the table writes it."""
    text = METHODS_PAGE.read_text(encoding="utf-8")
    return {kind: {name: default.strip().strip("`") for name, default in ROW.findall(body)}
            for kind, body in SECTION.findall(text)}


def _shown_default(field) -> str:
    value = field.default_factory() if field.default_factory is not None else field.default
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    return str(value)


def test_every_method_has_its_options_documented_with_their_defaults():
    from uqflow.methods import get_method
    with open(ROOT / "pyproject.toml", "rb") as fh:     # the project's own methods
        kinds = tomllib.load(fh)["project"]["entry-points"]["uqflow.methods"]
    docs = documented_options()
    assert len(kinds) >= 5
    for kind in kinds:
        assert kind in docs, f"docs/study-files.md has no section for kind = \"{kind}\""
        fields = get_method(kind).Options.model_fields
        assert set(docs[kind]) == set(fields), (kind, sorted(docs[kind]), sorted(fields))
        for name, field in fields.items():
            assert docs[kind][name] == _shown_default(field), (kind, name)


def test_fields_page_tables_match_the_code():
    """docs/fields.md: the kl-weibull options table and the [[fields]] keys with their defaults."""
    from uqflow.fields import FieldSpec, GermSpec
    from uqflow.methods import get_method
    text = (ROOT / "docs" / "fields.md").read_text(encoding="utf-8")
    method_table = text[text.index("## The `kl-weibull` method"):]
    rows = dict(ROW.findall(method_table.split("\n\n### ", 1)[0]))
    fields = get_method("kl-weibull").Options.model_fields
    assert set(rows) == set(fields)
    for name, field in fields.items():
        assert rows[name].strip().strip("`") == _shown_default(field), name

    keys = text[text.index("## Keys of a `[[fields]]` table"):].split("\n\n", 2)[1]
    documented = {}
    for key_cell, default in re.findall(r"^\| ([^|]+) \| ([^|]+) \|", keys, re.M)[1:]:
        names = re.findall(r"`([a-z_.]+)`", key_cell)
        values = [v.strip().strip("`") for v in default.split(",")] \
            if len(names) > 1 else [default.strip().strip("`")]
        documented.update(zip(names, values))
    spec = {**{k: v for k, v in FieldSpec.model_fields.items() if k != "germ"},
            **{f"germ.{k}": v for k, v in GermSpec.model_fields.items()}}
    assert set(documented) == set(spec)
    for name, field in spec.items():
        shown = documented[name]
        if field.is_required():
            assert shown == "required", name
        elif field.default is None:           # derived defaults, written as words
            assert shown == "—" or " if " in shown or shown == "[name]", (name, shown)
        else:
            assert shown.split(" if ")[0] == _shown_default(field), (name, shown)


# ----------------------------------------------------------------------------- python blocks
# Every ```python block of README.md and docs/*.md runs as written: saved as a script in a
# temporary folder that holds a copy of the project's studies/ (the studies and scenes it names
# shrunk as for the shipped-study runs, [execution] left as written) and the page's
# `# file:` blocks, then run as a script: a block that starts dask workers with
# `python <block>.py` in a subprocess, so that without `if __name__ == "__main__":` it fails
# here as it does for a reader; the others as `__main__` in this process (runpy).
# The line before a block may say what it needs, as an HTML comment a reader sees in the source:
#   <!-- after: uqflow run studies/x.toml -->  run that study first (in this process, shrunk)
#   <!-- fragment: why -->  not a whole program (an excerpt, an interface, a cluster we lack);
#                           it is not run, and there are at most MAX_FRAGMENTS of them.
PY_BLOCK = re.compile(r"^```python[ \t]*\n(.*?)^```", re.S | re.M)
PY_MARKER = re.compile(r"<!--\s*(fragment|after):\s*(\S.*?)\s*-->\s*$")
STUDY_PATH = re.compile(r"studies/[\w./-]+\.toml")
MAX_FRAGMENTS = 4
BLOCK_TIMEOUT = 300          # s; a dask block spends most of it importing in its workers


@dataclass
class PyBlock:
    page: Path
    line: int
    text: str
    marker: tuple[str, str]

    @property
    def id(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def python_blocks() -> list[PyBlock]:
    out = []
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for match in PY_BLOCK.finditer(text):
            before = [s for s in text[:match.start()].splitlines() if s.strip()]
            found = PY_MARKER.match(before[-1].strip()) if before else None
            marker = (found.group(1), found.group(2)) if found else ("", "")
            out.append(PyBlock(page, text.count("\n", 0, match.start()) + 1, match.group(1),
                               marker))
    return out


PY_BLOCKS = python_blocks()
RUNNABLE = [b for b in PY_BLOCKS if b.marker[0] != "fragment"]


def _shrink_file(path: Path) -> None:
    """Shrink, in place, a study (method counts, its scene file) or a scene file."""
    from test_shipped_studies import SHRUNK_COUNTS, _shrink_scene
    with open(path, "rb") as fh:
        data = tomllib.load(fh)
    if "solver" in data and "method" in data:
        method = data["method"]
        for key, cap in SHRUNK_COUNTS.items():
            if isinstance(method.get(key), int):
                method[key] = min(method[key], cap)
        if isinstance(data.get("scene"), str):
            _shrink_file(path.parent / data["scene"])
        elif isinstance(data.get("scene"), dict):
            data["scene"] = _shrink_scene(data["scene"], data["solver"])
    elif scene_solver(data) == "mpm":
        data = _shrink_scene(data, "mpm")
    else:
        return
    path.write_text(to_toml(data) + "\n", encoding="utf-8")


def prepare(block: PyBlock, folder: Path, monkeypatch) -> None:
    """The folder a reader would run the block in: studies/, the page's files, and what an
    `after:` marker names run first."""
    import shutil
    shutil.copytree(ROOT / "studies", folder / "studies")
    for toml_block in BLOCKS:
        kind, name = toml_block.marker
        if toml_block.page == block.page and kind == "file" and name != "pyproject.toml":
            (folder / name).parent.mkdir(parents=True, exist_ok=True)
            (folder / name).write_text(toml_block.text, encoding="utf-8")
    kind, command = block.marker
    for named in sorted(set(STUDY_PATH.findall(block.text + "\n" + command))):
        if (folder / named).is_file():
            _shrink_file(folder / named)
    if kind == "after":
        words = command.split()
        assert words[:2] == ["uqflow", "run"], f"{block.id}: after: takes 'uqflow run STUDY'"
        monkeypatch.chdir(folder)
        code = main([*words[1:], "--workers", "0", "--quiet", "--no-figures"])
        assert code == 0, f"{block.id}: '{command}' exited {code}"


def run_block(block: PyBlock, folder: Path) -> subprocess.CompletedProcess:
    """Run the block as `python doc_block.py` in ``folder``; AssertionError if it fails."""
    script = folder / "doc_block.py"
    script.write_text(block.text, encoding="utf-8")
    env = dict(os.environ, MPLBACKEND="Agg")
    done = subprocess.run([sys.executable, script.name], cwd=folder, env=env, text=True,
                          capture_output=True, timeout=BLOCK_TIMEOUT)
    assert done.returncode == 0, (
        f"{block.id} exited {done.returncode}:\n" + "\n".join(done.stderr.splitlines()[-15:]))
    return done


def run_block_here(block: PyBlock, folder: Path, monkeypatch) -> None:
    """Run a block that starts no worker processes as ``__main__`` in this process (saves a
    Python start and uqflow's import): a fresh namespace, so a missing import still fails;
    what it registers and the figures it opens do not outlive the test."""
    import runpy

    import matplotlib.pyplot as plt

    import uqflow.testing  # noqa: F401  (its tiny solver registers at first import: not in a copy)
    from uqflow.methods.base import method_registry
    from uqflow.solver import solver_registry
    for registry in (method_registry, solver_registry):
        for state in ("_classes", "_broken", "_entry_points_loaded"):   # restored as a whole
            monkeypatch.setattr(registry, state, getattr(registry, state))
        registry._classes, registry._broken = dict(registry._classes), dict(registry._broken)
    monkeypatch.chdir(folder)
    script = folder / "doc_block.py"
    script.write_text(block.text, encoding="utf-8")
    try:
        runpy.run_path(str(script), run_name="__main__")
    finally:
        plt.close("all")


def assert_results_keep_output_dims(folder: Path) -> None:
    """Every result a block wrote has statistics with the dims of the outputs they describe
    (a method that averaged y(t) into one number would teach the wrong thing)."""
    from uqflow.methods.base import output_names
    from uqflow.store import open_result
    for path in folder.rglob("*.nc"):
        tree = open_result(path)
        if "statistics" not in tree.children:
            continue
        runs, stats = tree["runs"].to_dataset(), tree["statistics"].to_dataset()
        for out in output_names(runs):
            assert stats[out].dims[1:] == runs[out].dims[1:], (path.name, out, stats[out].dims)


def test_the_pages_have_python_examples():
    assert len(RUNNABLE) >= 4
    assert {b.page.name for b in RUNNABLE} >= {"README.md", "results.md"}


def test_fragments_are_rare_and_say_why():
    fragments = [b for b in PY_BLOCKS if b.marker[0] == "fragment"]
    assert len(fragments) <= MAX_FRAGMENTS, [b.id for b in fragments]
    assert all(len(b.marker[1].split()) >= 3 for b in fragments), [b.id for b in fragments]


def test_blocks_that_start_dask_workers_guard_main():
    """A script that starts worker processes runs its study under `if __name__ ==
    "__main__":` (the workers import the script again; without it: "Nanny failed to start")."""
    assert any(_starts_workers(b) for b in RUNNABLE)
    for block in RUNNABLE:
        if _starts_workers(block):
            assert 'if __name__ == "__main__":' in block.text, block.id


def _starts_workers(block: PyBlock) -> bool:
    """Whether the block may start dask worker processes: a run_study without workers=0
    (the study's [execution] workers default to 2), or a LocalCluster."""
    calls = re.findall(r"run_study\(([^)]*)\)", block.text)
    return any(not re.search(r"workers\s*=\s*0\b", c) for c in calls) or \
        "LocalCluster(" in block.text


@pytest.mark.parametrize("block", [pytest.param(b, marks=pytest.mark.slow) if _starts_workers(b)
                                   else b for b in RUNNABLE], ids=[b.id for b in RUNNABLE])
def test_doc_python_block_runs(block, tmp_path, monkeypatch):
    prepare(block, tmp_path, monkeypatch)
    if _starts_workers(block):
        run_block(block, tmp_path)            # the workers import the script: a real one
    else:
        run_block_here(block, tmp_path, monkeypatch)
    assert_results_keep_output_dims(tmp_path)


def test_a_failing_block_fails(tmp_path, monkeypatch):
    """The runner can fail: a block that raises, and one that reduces y(t) to one number."""
    bad = PyBlock(ROOT / "README.md", 0, "import math\nmath.sqrt(-1)\n", ("", ""))
    with pytest.raises(AssertionError, match="ValueError"):
        run_block(bad, tmp_path)
    unimported = PyBlock(ROOT / "README.md", 0, "np.sqrt(2.0)\n", ("", ""))
    with pytest.raises(NameError):                  # this module's imports do not leak in
        run_block_here(unimported, tmp_path, monkeypatch)
    runs = xr.Dataset({"y": (("realization", "t"), np.ones((2, 3))),
                       "status": ("realization", ["ok", "ok"])}, coords={"t": [0.0, 1.0, 2.0]})
    stats = xr.Dataset({"y": (("statistic",), [1.0])}, coords={"statistic": ["mean"]})
    tree = xr.DataTree.from_dict({"runs": runs, "statistics": stats})
    tree.to_netcdf(tmp_path / "reduced.nc")
    with pytest.raises(AssertionError, match="reduced.nc"):
        assert_results_keep_output_dims(tmp_path)


def test_the_readme_selects_the_samples_the_statistics_use(tmp_path):
    """The README's selection of the Monte Carlo samples, run on a study with a control
    variate: it keeps the samples the statistics count (samples_ok), not the control runs."""
    import textwrap

    from uqflow.execute import run_study
    from uqflow.store import open_result
    block = next(b for b in RUNNABLE if b.page.name == "README.md" and "ishigami_mc" in b.text)
    lines = block.text.splitlines()
    first = next(k for k, s in enumerate(lines) if 'runs = tree["runs"]' in s)
    last = max(k for k, s in enumerate(lines) if s.lstrip().startswith("samples"))
    selection = textwrap.dedent("\n".join(lines[first:last + 1]))
    study = {**BASES["analytic"], "name": "controlled", "solver": "analytic",
             "method": {"kind": "monte-carlo", "samples": 16, "control": "taylor"},
             "execution": {"workers": 0}, "output": {"path": "controlled.nc", "figures": False}}
    (tmp_path / "controlled.toml").write_text(to_toml(study) + "\n", encoding="utf-8")
    tree = open_result(run_study(load_study(tmp_path / "controlled.toml"),
                                 show_progress=False).path)
    import uqflow
    namespace = {"tree": tree, "uqflow": uqflow}
    exec(selection, namespace)
    samples, runs = np.asarray(namespace["samples"]), namespace["runs"]
    assert int(samples.sum()) == tree["statistics"].attrs["samples_ok"] == 16
    assert int((runs.status == "ok").sum()) > 16          # with the control runs
    assert set(runs.role.values[samples]) == {"sample"}


# ----------------------------------------------------------------------------- figures
RESULTS_PAGE = ROOT / "docs" / "results.md"


def test_every_figure_the_report_draws_is_on_the_results_page():
    from uqflow.report.framework_figures import FRAMEWORK_FIGURES
    text = RESULTS_PAGE.read_text(encoding="utf-8")
    table = text[text.index("## The figures"):]
    for kind, _ in FRAMEWORK_FIGURES:
        assert f"| `<out>_{kind}.png` |" in table, kind


def test_the_convergence_figure_is_drawn_where_the_results_page_says(tmp_path):
    """docs/results.md: a monte-carlo trace for every output, the figure only with two or more
    sample counts (sobol: 2 x replicates samples; samples = replicates gives one)."""
    from uqflow.execute import run_study
    from uqflow.report import write_figures
    from uqflow.store import open_result

    def figures(name, method, relabel=None):
        study = {**BASES["analytic"], "name": name, "solver": "analytic", "method": method,
                 "execution": {"workers": 0}, "output": {"path": f"{name}.nc",
                                                         "figures": False}}
        (tmp_path / f"{name}.toml").write_text(to_toml(study) + "\n", encoding="utf-8")
        tree = open_result(run_study(load_study(tmp_path / f"{name}.toml"),
                                     show_progress=False).path)
        assert "y_trace" in tree["statistics"]
        if relabel:
            tree["statistics"].attrs["method"] = relabel
        return sorted(p.name for p in write_figures(tree, tmp_path / name))

    one_count = {"kind": "monte-carlo", "samples": 8, "rule": "sobol", "replicates": 8}
    two_counts = dict(one_count, samples=16)
    assert figures("one", one_count) == ["y_exceedance.png", "y_histogram.png"]
    assert figures("two", two_counts) == ["y_convergence.png", "y_exceedance.png",
                                          "y_histogram.png"]
    # kl-weibull draws its trace like Monte Carlo (its report hook, runs are draws)
    assert figures("kl", two_counts, relabel="kl-weibull") == ["y_convergence.png",
                                                               "y_exceedance.png",
                                                               "y_histogram.png"]


# ----------------------------------------------------------------------------- error lines
# The one-line errors the pages show for studies/plate.toml and studies/bad.toml, each made
# by the study it describes and compared with what the command prints.
ERROR_LINE = re.compile(r"(?:uqflow: error: )?(studies/(?:plate|bad)\.toml: [^`\n]+)")
_TWO_NORMALS = """
[[inputs]]
name = "x1"
distribution = "normal"
mean = 1.0
std = 0.1

[[inputs]]
name = "x2"
distribution = "normal"
mean = 1.0
std = 0.1
"""
_CORRELATION = '\n[correlation]\ninputs = ["x1", "x2"]\nmatrix = [[1.0, {r}], [{r}, 1.0]]\n'
ERROR_CASES = {   # (file, key) -> (command, the study's tables after its solver and scene)
    ("bad", "inputs[0].cv"): ("validate", '\n[[inputs]]\nname = "x1"\ndistribution = "normal"'
                              '\nmean = 1.0\ncv = -0.1\n\n[method]\nkind = "monte-carlo"\n'),
    ("bad", "inputs[0].std"): ("validate", '\n[[inputs]]\nname = "x1"\ndistribution = "normal"'
                               '\nmean = 0.0\nstd = 1e77\n\n[method]\nkind = "monte-carlo"\n'),
    ("plate", "inputs[1].upper"): ("validate", _TWO_NORMALS.rsplit("[[inputs]]", 1)[0]
                                   + '[[inputs]]\nname = "x2"\ndistribution = "uniform"\n'
                                     'lower = 0.0\nupper = 0.0\n\n[method]\n'
                                     'kind = "monte-carlo"\n'),
    ("plate", "method.samples"): ("validate", _TWO_NORMALS + '\n[method]\nkind = "monte-carlo"'
                                              '\nsamples = "many"\n'),
    ("plate", "correlation.matrix"): ("validate", _TWO_NORMALS + _CORRELATION.format(r=1.0)
                                      + '\n[method]\nkind = "monte-carlo"\n'),
    ("plate", "method.kind"): ("validate", _TWO_NORMALS + _CORRELATION.format(r=0.5)
                               + '\n[method]\nkind = "sobol"\n'),
    ("plate", "output.path"): ("run", _TWO_NORMALS + '\n[method]\nkind = "monte-carlo"\n'
                                                     'samples = 4\n'),
}


def documented_error_lines() -> list[tuple[str, str]]:
    return [(page.name, line.strip()) for page in PAGES
            for line in ERROR_LINE.findall(page.read_text(encoding="utf-8"))]


def printed_error(case: tuple[str, str], folder: Path, capsys) -> str:
    name, _ = case
    command, tables = ERROR_CASES[case]
    (folder / "studies").mkdir(exist_ok=True)
    study = folder / "studies" / f"{name}.toml"
    study.write_text(f'name = "{name}"\nsolver = "analytic"\nscene = {{ model = "linear", '
                     f'coefficients = [1.0, 1.0] }}\n{tables}', encoding="utf-8")
    if case[1] == "output.path":                  # a result already there
        (folder / "studies" / "results").mkdir(exist_ok=True)
        (folder / "studies" / "results" / f"{name}.nc").write_bytes(b"")
    capsys.readouterr()
    code = main([command, f"studies/{name}.toml"])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    return err.replace(str(folder.resolve()) + "/", "/home/me/project/")


def test_the_pages_show_error_lines():
    shown = documented_error_lines()
    assert len(shown) >= 7
    assert {page for page, _ in shown} >= {"README.md", "inputs.md", "study-files.md"}


@pytest.mark.parametrize("page, line", documented_error_lines())
def test_a_documented_error_line_is_what_uqflow_prints(page, line, tmp_path, monkeypatch,
                                                      capsys):
    file, key = re.match(r"studies/(\w+)\.toml: ([^:]+):", line).groups()
    assert (file, key) in ERROR_CASES, f"{page}: add a case for {file}.toml {key}"
    monkeypatch.chdir(tmp_path)
    assert printed_error((file, key), tmp_path, capsys) == f"uqflow: error: {line}"


# ----------------------------------------------------------------------------- named files
NAMED_PATH = re.compile(r"(?<![\w/.$])((?:tests|uqflow|solvers|studies|benchmarks|docs|figures|"
                        r"shared|\.ci)/[\w./-]*[\w])(?![\w{*\[])")
# error examples: the study is described, not shipped (test_a_documented_error_line_...)
EXAMPLE_FILES = {"studies/plate.toml", "studies/bad.toml"}


def test_every_file_a_page_names_exists():
    """A page names files of this project only (nothing outside it, such as a shared folder),
    and each exists, or is a `# file:` block of that page or an error example."""
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        shown = {b.marker[1] for b in BLOCKS if b.page == page and b.marker[0] == "file"}
        for named in set(NAMED_PATH.findall(text)):
            if named in EXAMPLE_FILES or named in shown:
                continue
            assert any((base / named).exists() for base in (ROOT, ROOT / "docs",
                                                             ROOT / "studies")), \
                f"{page.name} names {named}, which is not in the project"


def test_every_design_variable_is_on_the_results_page(tmp_path):
    """docs/results.md, group runs: each variable and coordinate a method's design adds (over
    the shipped analytic studies, and Monte Carlo with a control variate) is named there."""
    from uqflow.study import load_study as load
    text = RESULTS_PAGE.read_text(encoding="utf-8")
    section = text[text.index("## Group `runs`"):text.index("## Group `statistics`")]
    paths = [p for p in sorted((ROOT / "studies").rglob("*.toml")) if "scenes" not in p.parts
             and tomllib.loads(p.read_text(encoding="utf-8")).get("solver") == "analytic"]
    controlled = {**BASES["analytic"], "name": "controlled", "solver": "analytic",
                  "method": {"kind": "monte-carlo", "samples": 16, "control": "taylor"}}
    (tmp_path / "controlled.toml").write_text(to_toml(controlled) + "\n", encoding="utf-8")
    named = set()
    for path in [*paths, tmp_path / "controlled.toml"]:
        study = load(path)
        design = study.method.plan(study.space, study.fields, np.random.SeedSequence(0))
        named |= set(design.data_vars) | set(design.coords)
    assert {"role", "level", "stencil"} <= named
    for name in sorted(named):
        assert f"`{name}`" in section, f"docs/results.md, group runs, does not name {name}"


def test_the_exit_codes_table_is_the_command_lines():
    """docs/execution.md, "Exit codes of `uqflow`": one row per exit code the CLI has."""
    from uqflow import cli
    text = (ROOT / "docs" / "execution.md").read_text(encoding="utf-8")
    table = text[text.index("## Exit codes of `uqflow`"):].split("\n\n")[1]
    documented = {int(code) for code in re.findall(r"^\| (\d+) \|", table, re.M)}
    codes = {0} | {v for k, v in vars(cli).items() if k.startswith("EXIT_")}
    assert documented == codes


def test_the_models_without_local_derivatives_are_named_right():
    """README and study-files.md name the analytic models that taylor-local cannot use."""
    from solvers.analytic.models import MODELS
    without = {name for name, model in MODELS.items() if not hasattr(model, "derivatives")}
    for page in (ROOT / "README.md", METHODS_PAGE):
        text = " ".join(page.read_text(encoding="utf-8").split())
        named = re.search(r"the analytic models other than `(\w+)` and `(\w+)`", text)
        assert named, f"{page.name} does not say which analytic models lack local derivatives"
        assert set(named.groups()) == without, page.name


def test_the_field_cache_is_as_the_fields_page_says():
    from uqflow import fields
    text = " ".join((ROOT / "docs" / "fields.md").read_text(encoding="utf-8").split())
    slots, power = re.search(r"for the last (\d+) point sets, up to 2(\S+) ", text).groups()
    superscript = str.maketrans("⁰¹²³⁴⁵⁶⁷⁸⁹", "0123456789")
    assert int(slots) == fields._CACHE_SLOTS
    assert 2 ** int(power.translate(superscript)) == fields._CACHE_ENTRIES


def test_every_variable_and_attribute_of_a_result_is_on_the_results_page(tmp_path):
    """docs/results.md: the runs group names every variable and coordinate a result's runs
    have (a control-variate Monte Carlo study, run here), the statistics section (with the
    control-variate page it links to) every attribute its statistics have."""
    from uqflow.execute import run_study
    from uqflow.methods.base import output_names
    from uqflow.store import open_result
    text = RESULTS_PAGE.read_text(encoding="utf-8")
    runs_section = text[text.index("## Group `runs`"):text.index("## Group `statistics`")]
    stats_section = text[text.index("## Group `statistics`"):text.index("## Post-processing")]
    control = (ROOT / "docs" / "control_variates.md").read_text(encoding="utf-8")
    stats_section += control[control.index("## What the statistics report"):]   # linked there
    study = {**BASES["analytic"], "name": "controlled", "solver": "analytic",
             "method": {"kind": "monte-carlo", "samples": 8, "control": "taylor"},
             "execution": {"workers": 0}, "output": {"path": "controlled.nc", "figures": False}}
    (tmp_path / "controlled.toml").write_text(to_toml(study) + "\n", encoding="utf-8")
    tree = open_result(run_study(load_study(tmp_path / "controlled.toml"),
                                 show_progress=False).path)
    runs, stats = tree["runs"].to_dataset(), tree["statistics"]
    for name in sorted(set(runs.variables) - set(output_names(runs))):
        assert f"`{name}`" in runs_section, f"group runs does not name {name}"
    for name in sorted(stats.attrs):
        assert f"`{name}`" in stats_section, f"group statistics does not name attribute {name}"


# ----------------------------------------------------------------------------- links
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _anchors(page: Path) -> set[str]:
    """GitHub's heading anchors: of the heading as rendered (a link shows its text only),
    lower case, punctuation dropped, spaces to hyphens."""
    return {re.sub(r"[^\w\- ]", "", re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1",
                                           heading.strip()).lower()).replace(" ", "-")
            for heading in re.findall(r"^#+\s+(.*)$", page.read_text(encoding="utf-8"), re.M)}


def broken_links(page: Path, text: str) -> list[str]:
    broken = []
    for target in LINK.findall(text):
        if target.startswith(("http://", "https://", "mailto:")):
            continue
        path, _, anchor = target.partition("#")
        linked = page.parent / path if path else page
        if not linked.exists() or (anchor and linked.suffix == ".md"
                                   and anchor not in _anchors(linked)):
            broken.append(target)
    return broken


def test_every_link_between_the_pages_resolves():
    for page in PAGES:
        assert broken_links(page, page.read_text(encoding="utf-8")) == [], page.name
    readme = ROOT / "README.md"
    assert broken_links(readme, "[x](docs/results.md#no-such-section) [y](docs/gone.md)") == \
        ["docs/results.md#no-such-section", "docs/gone.md"]


def test_the_lock_file_is_named_as_the_execution_page_says():
    from uqflow.store import lock_path
    text = (ROOT / "docs" / "execution.md").read_text(encoding="utf-8")
    named = re.search(r"lock file beside the result \(`<result>(\.\w+)`", text)
    assert named, "docs/execution.md does not name the result's lock file"
    assert lock_path(Path("r.nc")).name == "r.nc" + named.group(1)
