"""Study files: every mistake is ONE line naming the file and the key, exit code 2, no file.

The table of malformed studies runs in-process through ``uqflow.cli.main`` (the same code path
as the console script, minus the interpreter start); the cases marked ``subprocess`` run the
real ``python -m uqflow.cli`` to prove the exit code and the absence of a traceback. Every case
also goes through ``uqflow validate``, which must catch everything ``uqflow run`` would.
"""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from uqflow import cli
from uqflow.store import open_result

REPO = Path(__file__).resolve().parents[1]

# A valid study: every case below breaks exactly one thing in it. Its result would go to
# out/result.nc beside the study file, i.e. tmp_path / "out", which must never appear.
BASE = """\
name = "probe"
solver = "analytic"
scene = { model = "linear", coefficients = [1.0, 2.0] }

[[inputs]]
name = "x1"
distribution = "normal"
mean = 1.0
std = 0.1

[[inputs]]
name = "x2"
distribution = "uniform"
lower = 0.0
upper = 1.0

[method]
kind = "monte-carlo"
samples = 8

[execution]
workers = 0

[output]
path = "out/result.nc"
figures = false
"""

CORRELATION = """
[correlation]
inputs = ["x1", "x2"]
matrix = [[1.0, 0.5], [0.5, 1.0]]
"""


def replace(old: str, new: str):
    def edit(text: str) -> str:
        assert text.count(old) == 1, f"the case's edit must hit BASE exactly once: {old!r}"
        return text.replace(old, new)
    return edit


def append(extra: str):
    return lambda text: text + extra


def prepend(extra: str):
    return lambda text: extra + text


@dataclass
class Case:
    id: str
    key: str | None                 # the key the message must name (None: none, TOML syntax)
    edits: tuple = ()
    says: str = ""                  # words the reason must contain
    files: dict = field(default_factory=dict)   # more files beside the study (relative path)
    names: str | None = None        # file the message names, relative to tmp_path; default study
    subprocess: bool = False        # run the real interpreter


SCENE_KEY = 'scene = { model = "linear", coefficients = [1.0, 2.0] }'
METHOD = 'kind = "monte-carlo"\nsamples = 8'

CASES = [
    # --- the file itself
    Case("toml-syntax-error", None, (replace("samples = 8", "samples = = 8"),),
         says="not valid TOML", subprocess=True),
    Case("unknown-top-level-key", "colour", (prepend('colour = "red"\n'),), says="unknown key"),
    Case("missing-method-table", "method", (replace(f"[method]\n{METHOD}\n", ""),),
         says="required key is missing"),
    Case("missing-name", "name", (replace('name = "probe"\n', ""),),
         says="required key is missing"),
    # --- solver and scene
    Case("unknown-solver", "solver", (replace('solver = "analytic"', 'solver = "abaqus"'),),
         says="unknown solver 'abaqus'"),
    Case("scene-not-table-or-path", "scene", (replace(SCENE_KEY, "scene = 3"),),
         says="inline table"),
    Case("unknown-analytic-model", "scene.model",
         (replace('model = "linear"', 'model = "rosenbrock"'),),
         says="unknown analytic model 'rosenbrock'", subprocess=True),
    Case("unknown-scene-key", "scene.colour",
         (replace("coefficients = [1.0, 2.0] }", "coefficients = [1.0, 2.0], colour = 1 }"),),
         says="unknown key"),
    Case("scene-value-wrong-type", "scene.coefficients",
         (replace("coefficients = [1.0, 2.0]", 'coefficients = "steep"'),),
         says="list of finite numbers"),
    Case("scene-file-does-not-exist", "scene",
         (replace(SCENE_KEY, 'scene = "scenes/missing.toml"'),), says="no such scene file"),
    Case("scene-file-unknown-model", "scene.model",
         (replace(SCENE_KEY, 'scene = "scenes/bad.toml"'),),
         files={"scenes/bad.toml": 'model = "rosenbrock"\n'}, names="scenes/bad.toml",
         says="unknown analytic model"),
    # --- inputs
    Case("inputs-single-brackets", "inputs",
         (replace('[[inputs]]\nname = "x1"', '[inputs]\nname = "x1"'),
          replace('[[inputs]]\nname = "x2"\ndistribution = "uniform"\nlower = 0.0\n'
                  'upper = 1.0\n', "")),
         says="[[inputs]]"),
    Case("no-inputs", "inputs",
         (replace('[[inputs]]\nname = "x1"\ndistribution = "normal"\nmean = 1.0\nstd = 0.1\n\n'
                  '[[inputs]]\nname = "x2"\ndistribution = "uniform"\nlower = 0.0\n'
                  'upper = 1.0\n\n', ""),),
         says="at least one uncertain input"),
    Case("unknown-key-in-input", "inputs[0].stdev", (replace("std = 0.1", "stdev = 0.1"),),
         says="unknown key (did you mean 'std'?)"),
    Case("input-missing-distribution", "inputs[1].distribution",
         (replace('distribution = "uniform"\n', ""),), says="required key is missing"),
    Case("unknown-distribution", "inputs[0].distribution",
         (replace('distribution = "normal"', 'distribution = "gumbel"'),),
         says="unknown distribution 'gumbel'"),
    Case("number-is-a-string", "inputs[0].std", (replace("std = 0.1", 'std = "small"'),),
         says="valid number"),
    Case("number-is-a-boolean", "inputs[0].std", (replace("std = 0.1", "std = true"),),
         says="must be a number"),
    Case("negative-std", "inputs[0].std", (replace("std = 0.1", "std = -0.1"),),
         says=">= 0"),
    Case("cv-on-zero-mean", "inputs[0].cv",
         (replace("mean = 1.0\nstd = 0.1", "mean = 0.0\ncv = 0.1"),), says="nonzero mean"),
    Case("std-and-cv-both", "inputs[0].cv", (replace("std = 0.1", "std = 0.1\ncv = 0.1"),),
         says="not both"),
    Case("mean-without-spread", "inputs[0].std", (replace("std = 0.1\n", ""),),
         says="std or cv"),
    Case("lognormal-mean-not-positive", "inputs[0].mean",
         (replace('distribution = "normal"\nmean = 1.0',
                  'distribution = "lognormal"\nmean = -1.0'),), says="> 0"),
    Case("upper-not-above-lower", "inputs[1].upper", (replace("upper = 1.0", "upper = 0.0"),),
         says="must exceed lower", subprocess=True),
    # issue 8: a value whose moments overflow float64 was an OverflowError traceback
    Case("std-overflows-the-moments", "inputs[0].std", (replace("std = 0.1", "std = 1e308"),),
         says="overflow"),
    Case("lognormal-variance-overflows", "inputs[0].sigma",
         (replace('distribution = "normal"\nmean = 1.0\nstd = 0.1',
                  'distribution = "lognormal"\nmu = 0.0\nsigma = 30.0'),), says="overflow"),
    Case("weibull-shape-too-small-for-gamma", "inputs[1].shape",
         (replace('distribution = "uniform"\nlower = 0.0\nupper = 1.0',
                  'distribution = "weibull"\nshape = 0.001\nscale = 1.0'),),
         says="fourth moment overflows"),
    Case("mean-is-nan", "inputs[0].mean", (replace("mean = 1.0", "mean = nan"),),
         says="finite number"),
    Case("parameter-of-another-distribution", "inputs[0].alpha",
         (replace("std = 0.1", "std = 0.1\nalpha = 2.0"),), says="not a parameter"),
    Case("input-not-a-solver-parameter", "inputs[1].name",
         (replace('name = "x2"', 'name = "E"'),), says="not a parameter of this solver"),
    Case("duplicate-input-name", "inputs[1].name", (replace('name = "x2"', 'name = "x1"'),),
         says="declared twice"),
    # --- correlation
    Case("correlation-not-positive-definite", "correlation.matrix",
         (append(CORRELATION.replace("0.5", "1.0")),), says="not positive definite",
         subprocess=True),
    Case("correlation-not-symmetric", "correlation.matrix",
         (append(CORRELATION.replace("[[1.0, 0.5]", "[[1.0, 0.4]")),), says="symmetric"),
    Case("correlation-unknown-input", "correlation.inputs[1]",
         (append(CORRELATION.replace('"x2"]', '"x9"]')),), says="'x9'"),
    Case("correlation-wrong-shape", "correlation.matrix",
         (append(CORRELATION.replace("[[1.0, 0.5], [0.5, 1.0]]", "[[1.0, 0.5, 0.0]]")),),
         says="2x2"),
    Case("correlation-entry-nan", "correlation.matrix[0][1]",
         (append(CORRELATION.replace("[[1.0, 0.5]", "[[1.0, nan]")),), says="finite number"),
    Case("correlation-entry-not-a-number", "correlation.matrix[0][1]",
         (append(CORRELATION.replace("[[1.0, 0.5]", '[[1.0, "half"]')),), says="valid number"),
    # --- outputs
    Case("unknown-output", "outputs[0]",
         (replace('solver = "analytic"', 'solver = "analytic"\noutputs = ["stress"]'),),
         says="no output 'stress'"),
    Case("output-listed-twice", "outputs[1]",
         (replace('solver = "analytic"', 'solver = "analytic"\noutputs = ["y", "y"]'),),
         says="listed twice"),
    Case("output-name-blank", "outputs[0]",
         (replace('solver = "analytic"', 'solver = "analytic"\noutputs = [" "]'),),
         says="blank"),
    Case("outputs-not-a-list", "outputs",
         (replace('solver = "analytic"', 'solver = "analytic"\noutputs = "y"'),),
         says="valid list"),
    # --- method
    Case("unknown-method-kind", "method.kind",
         (replace('kind = "monte-carlo"', 'kind = "polynomial-chaos"'),),
         says="unknown method 'polynomial-chaos'"),
    Case("samples-not-an-integer", "method.samples", (replace("samples = 8", 'samples = "many"'),),
         says="valid integer", subprocess=True),
    Case("samples-zero", "method.samples", (replace("samples = 8", "samples = 0"),),
         says="greater than or equal to 1"),
    # issue 8: true ran one sample, 1e15 died later in a MemoryError
    Case("samples-boolean", "method.samples", (replace("samples = 8", "samples = true"),),
         says="must be an integer, not a boolean, got true"),
    Case("samples-float-without-fraction", "method.samples",
         (replace("samples = 8", "samples = 8.0"),), says="write 8, not 8.0"),
    Case("samples-numeric-string", "method.samples", (replace("samples = 8", 'samples = "8"'),),
         says="valid integer"),
    Case("samples-beyond-memory", "method.samples", (replace("samples = 8", "samples = 1e15"),),
         says="must be an integer"),
    Case("samples-integer-beyond-bound", "method.samples",
         (replace("samples = 8", "samples = 1_000_000_000_000_000"),),
         says="must be <= 10,000,000"),
    Case("taylor-order-boolean", "method.order",
         (replace(METHOD, 'kind = "taylor"\norder = true'),), says="not a boolean"),
    Case("float-option-nan", "method.confidence",
         (replace("samples = 8", "samples = 8\nconfidence = nan"),), says="finite number"),
    Case("quantile-out-of-range", "method.quantiles",
         (replace("samples = 8", "samples = 8\nquantiles = [1.5]"),), says="[0, 1]"),
    Case("unknown-sampling-rule", "method.rule",
         (replace("samples = 8", 'samples = 8\nrule = "grid"'),), says="'lhs'"),
    Case("unknown-method-option", "method.sample", (replace("samples = 8", "sample = 8"),),
         says="unknown key (did you mean 'samples'?)"),
    Case("sobol-with-correlated-inputs", "method.kind",
         (replace('kind = "monte-carlo"', 'kind = "sobol"'), append(CORRELATION)),
         says="independent inputs", subprocess=True),
    Case("taylor-order-out-of-range", "method.order",
         (replace(METHOD, 'kind = "taylor"\norder = 3'),), says="1 or 2"),
    Case("union-option-wrong-type", "method.mixed_derivatives",
         (replace(METHOD, 'kind = "taylor"\nmixed_derivatives = "sometimes"'),),
         says="Input should be 'auto' or a valid boolean"),
    # --- execution
    Case("workers-negative", "execution.workers", (replace("workers = 0", "workers = -1"),),
         says="greater than or equal to 0"),
    Case("workers-numeric-string", "execution.workers", (replace("workers = 0", 'workers = "2"'),),
         says="valid integer"),
    Case("workers-beyond-bound", "execution.workers", (replace("workers = 0", "workers = 100000"),),
         says="less than or equal to 512"),
    Case("seed-beyond-64-bits", "execution.seed",
         (replace("workers = 0", "workers = 0\nseed = 18446744073709551616"),),
         says="less than or equal to 18446744073709551615"),
    Case("scheduler-malformed", "execution.scheduler",
         (replace("workers = 0", 'workers = 0\nscheduler = "tcp//10.0.0.5:8786"'),),
         says="not a scheduler address"),
    Case("scheduler-port-out-of-range", "execution.scheduler",
         (replace("workers = 0", 'workers = 0\nscheduler = "tcp://10.0.0.5:99999"'),),
         says="port in 1..65535"),
    Case("seed-not-an-integer", "execution.seed",
         (replace("workers = 0", "workers = 0\nseed = 1.5"),), says="valid integer"),
    Case("max-failure-fraction-above-one", "execution.max_failure_fraction",
         (replace("workers = 0", "workers = 0\nmax_failure_fraction = 2.0"),),
         says="less than or equal to 1"),
    Case("unknown-execution-key", "execution.threads",
         (replace("workers = 0", "threads = 4"),), says="unknown key (known: workers,"),
    # --- output
    Case("output-path-not-nc", "output.path",
         (replace('path = "out/result.nc"', 'path = "out/result.csv"'),), says=".nc"),
    Case("figures-not-a-boolean", "output.figures",
         (replace("figures = false", 'figures = "no"'),), says="valid boolean"),
]


def _param(case: Case):
    return pytest.param(case, id=case.id)


def write_case(case: Case, folder: Path) -> Path:
    text = BASE
    for edit in case.edits:
        text = edit(text)
    for rel, content in case.files.items():
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        (folder / rel).write_text(content)
    path = folder / "study.toml"
    path.write_text(text)
    return path


def run_in_process(args: list[str], capsys, monkeypatch, cwd: Path) -> tuple[int, str, str]:
    monkeypatch.delenv("UQFLOW_DEBUG", raising=False)
    monkeypatch.chdir(cwd)
    code = cli.main(args)
    out, err = capsys.readouterr()
    return code, out, err


def run_subprocess(args: list[str], cwd: Path) -> tuple[int, str, str]:
    env = {k: v for k, v in os.environ.items() if k != "UQFLOW_DEBUG"}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH")) if p)
    proc = subprocess.run([sys.executable, "-m", "uqflow.cli", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)
    return proc.returncode, proc.stdout, proc.stderr


def assert_one_line_error(err: str, file: Path, key: str | None, says: str = "") -> str:
    """stderr is exactly one line 'uqflow: error: <file>: <key>: <reason>'; returns it."""
    assert "Traceback" not in err, err
    assert err.endswith("\n") and err.count("\n") == 1, f"not exactly one line:\n{err}"
    line = err.rstrip("\n")
    prefix = f"uqflow: error: {file}: " + (f"{key}: " if key else "")
    assert line.startswith(prefix), f"expected {prefix!r}...\ngot      {line!r}"
    reason = line[len(prefix):]
    assert reason.strip(), line
    assert says in reason, f"reason should say {says!r}: {line!r}"
    # No pydantic noise: the user reads a sentence, not a validator's repr.
    for noise in ("[type=", "input_value", "For further information", "pydantic"):
        assert noise not in line, line
    return line


@pytest.mark.parametrize("case", [_param(c) for c in CASES])
def test_malformed_study_fails_in_one_line_and_writes_nothing(case, tmp_path, capsys,
                                                              monkeypatch):
    path = write_case(case, tmp_path)
    args = ["run", str(path)]
    if case.subprocess:
        code, out, err = run_subprocess(args, tmp_path)
    else:
        code, out, err = run_in_process(args, capsys, monkeypatch, tmp_path)
    assert code == 2, err
    named = tmp_path / case.names if case.names else path
    assert_one_line_error(err, named, case.key, case.says)
    assert out == ""
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("case", [_param(c) for c in CASES])
def test_validate_catches_what_run_would(case, tmp_path, capsys, monkeypatch):
    path = write_case(case, tmp_path)
    code, out, err = run_in_process(["validate", str(path)], capsys, monkeypatch, tmp_path)
    assert code == 2, err
    named = tmp_path / case.names if case.names else path
    assert_one_line_error(err, named, case.key, case.says)
    assert out == ""
    assert not (tmp_path / "out").exists()


def test_table_covers_enough_cases():
    assert len(CASES) >= 20
    assert len({c.id for c in CASES}) == len(CASES)
    assert 3 <= sum(c.subprocess for c in CASES) <= 6


def test_base_study_is_valid(tmp_path, capsys, monkeypatch):
    """Every case is BASE with one thing broken, so BASE itself must validate."""
    path = tmp_path / "study.toml"
    path.write_text(BASE)
    code, out, err = run_in_process(["validate", str(path)], capsys, monkeypatch, tmp_path)
    assert (code, err) == (0, "")
    assert out.startswith(f"{path}: ok (analytic, monte-carlo, 2 random inputs, outputs y)")


@pytest.mark.parametrize("variant", [
    pytest.param("", id="monte-carlo"),
    pytest.param(CORRELATION, id="monte-carlo-correlated"),
])
def test_validate_good_file_exits_0_prints_ok_and_creates_nothing(variant, tmp_path, capsys,
                                                                   monkeypatch):
    path = tmp_path / "study.toml"
    path.write_text(BASE.replace('path = "out/result.nc"', 'path = "out/deep/result.nc"')
                    + variant)
    code, out, err = run_in_process(["validate", str(path)], capsys, monkeypatch, tmp_path)
    assert code == 0 and err == ""
    assert out.count("\n") == 1 and out.startswith(f"{path}: ok")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["study.toml"]


def test_validate_several_files_stops_at_the_first_bad_one(tmp_path, capsys, monkeypatch):
    good, bad = tmp_path / "good.toml", tmp_path / "bad.toml"
    good.write_text(BASE)
    bad.write_text(BASE.replace("samples = 8", "samples = 0"))
    code, out, err = run_in_process(["validate", str(good), str(bad)], capsys, monkeypatch,
                                    tmp_path)
    assert code == 2
    assert out.startswith(f"{good}: ok")
    assert_one_line_error(err, bad, "method.samples")


def test_validate_the_shipped_quickstart(capsys, monkeypatch):
    study = REPO / "studies" / "quickstart.toml"
    code, out, err = run_in_process(["validate", str(study)], capsys, monkeypatch, REPO)
    assert (code, err) == (0, "")
    assert out.startswith(f"{study}: ok")


def test_missing_study_file(tmp_path, capsys, monkeypatch):
    path = tmp_path / "nowhere.toml"
    code, out, err = run_in_process(["run", str(path)], capsys, monkeypatch, tmp_path)
    assert code == 2
    assert_one_line_error(err, path, None, "file not found")


def test_run_onto_existing_result_refuses_and_leaves_it_alone(tmp_path, capsys, monkeypatch):
    path = tmp_path / "study.toml"
    path.write_text(BASE)
    result = tmp_path / "out" / "result.nc"
    result.parent.mkdir()
    content = b"an earlier result, not to be touched\x00\x01"
    result.write_bytes(content)
    before = result.stat().st_mtime_ns
    code, out, err = run_in_process(["run", str(path), "--quiet"], capsys, monkeypatch,
                                    tmp_path)
    assert code == 2
    line = assert_one_line_error(err, path, "output.path", "--resume")
    assert "--force" in line and str(result) in line
    assert out == ""
    assert result.read_bytes() == content and result.stat().st_mtime_ns == before
    assert sorted(p.name for p in result.parent.iterdir()) == ["result.nc"]


def test_relative_scene_and_output_paths_resolve_against_the_study_folder(tmp_path):
    """Run from another folder, naming the study by a relative path: the scene file and the
    result are found and written beside the study, nothing lands in the working folder, and
    the scene file's options are the ones the solver used."""
    project = tmp_path / "project" / "studies"
    (project / "scenes").mkdir(parents=True)
    (project / "scenes" / "line.toml").write_text(
        'model = "linear"\ncoefficients = [3.0]\noffset = 1.0\n')
    (project / "study.toml").write_text("""\
name = "relative"
solver = "analytic"
scene = "scenes/line.toml"

[[inputs]]
name = "x1"
distribution = "normal"
mean = 2.0
std = 0.5

[method]
kind = "monte-carlo"
samples = 6

[execution]
workers = 0
seed = 3

[output]
path = "../results/relative.nc"
figures = false
""")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    rel = os.path.relpath(project / "study.toml", elsewhere)
    code, out, err = run_subprocess(["run", rel, "--quiet"], elsewhere)
    assert code == 0, err
    result = tmp_path / "project" / "results" / "relative.nc"
    assert result.is_file()
    assert f"result: {result}" in out
    assert list(elsewhere.iterdir()) == []

    runs = open_result(result)["runs"].to_dataset()
    x = runs["inputs"].values[:, 0]
    assert runs.sizes["realization"] == 6
    assert np.all(runs["status"].values == "ok")
    # Bound: the solver's c0 + c x and this 1 + 3 x each round twice; with x ~ 2 +- 0.5
    # (y >= 2.5 for 3-sigma draws) that is a few eps of y, far below 1e-12.
    np.testing.assert_allclose(runs["y"].values, 1.0 + 3.0 * x, rtol=1e-12)


def test_scene_given_as_a_file_path_validates_like_the_inline_table(tmp_path, capsys,
                                                                     monkeypatch):
    (tmp_path / "scene.toml").write_text('model = "linear"\ncoefficients = [1.0, 2.0]\n')
    path = tmp_path / "study.toml"
    path.write_text(BASE.replace(SCENE_KEY, 'scene = "scene.toml"'))
    code, out, err = run_in_process(["validate", str(path)], capsys, monkeypatch, tmp_path)
    assert (code, err) == (0, "")
    assert out.startswith(f"{path}: ok (analytic, monte-carlo, 2 random inputs, outputs y)")


def test_absolute_output_path_is_kept(tmp_path):
    from uqflow.study import load_study

    target = tmp_path / "somewhere" / "else.nc"
    path = tmp_path / "sub" / "study.toml"
    path.parent.mkdir()
    path.write_text(BASE.replace('path = "out/result.nc"', f'path = "{target.as_posix()}"'))
    assert load_study(path).output_path == target


def test_default_output_path_is_results_slash_name_beside_the_study(tmp_path):
    from uqflow.study import load_study

    path = tmp_path / "study.toml"
    path.write_text(BASE.replace('path = "out/result.nc"\n', ""))
    assert load_study(path).output_path == (tmp_path / "results" / "probe.nc").resolve()


def _toml_blocks(markdown: str) -> list[str]:
    blocks, inside, lines = [], False, []
    for line in markdown.splitlines():
        if line.strip() == "```toml" and not inside:
            inside, lines = True, []
        elif line.strip() == "```" and inside:
            inside = False
            blocks.append("\n".join(lines) + "\n")
        elif inside:
            lines.append(line)
    return blocks


def test_documented_examples_validate(tmp_path, capsys, monkeypatch):
    """The opening example and every example of docs/study-files.md are complete, valid
    studies; a block starting with '# file: PATH' is a file the next studies use."""
    doc = (REPO / "docs" / "study-files.md").read_text()
    head, examples = doc.split("\n## Examples\n", 1)
    studies = [_toml_blocks(head)[0]]
    for block in _toml_blocks(examples):
        first = block.splitlines()[0]
        if first.startswith("# file: "):
            target = tmp_path / "docs" / first.removeprefix("# file: ").strip()
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(block)
        else:
            studies.append(block)
    assert len(studies) >= 4
    for i, text in enumerate(studies):
        path = tmp_path / "docs" / f"example{i}.toml"
        path.parent.mkdir(exist_ok=True)
        path.write_text(text)
        code, out, err = run_in_process(["validate", str(path)], capsys, monkeypatch, tmp_path)
        assert (code, err) == (0, ""), f"example {i}:\n{text}"
        assert out.startswith(f"{path}: ok")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["docs"]


def test_union_members_never_show_up_as_keys():
    """pydantic puts the union member it tried into ``loc`` ('dict[str,any]', 'str', ...);
    the key shown is the user's, with or without the data to walk."""
    from typing import Any, Literal

    from pydantic import BaseModel, ValidationError

    from uqflow.study import validation_error

    class Inner(BaseModel):
        mode: Literal["auto"] | bool = "auto"
        level: float | None = None

    class Outer(BaseModel):
        scene: dict[str, Any] | str
        items: list[Inner] = []

    for data, key in [({"scene": 3}, "scene"),
                      ({"scene": {}, "items": [{}, {"mode": "x"}]}, "items[1].mode"),
                      ({"scene": {}, "items": [{"level": "high"}]}, "items[0].level")]:
        with pytest.raises(ValidationError) as info:
            Outer.model_validate(data)
        for given in (data, None):
            err = validation_error(info.value, "f.toml", data=given)
            assert err.key == key, (data, given, str(err))
            assert str(err).startswith(f"f.toml: {key}: ")
            assert "\n" not in str(err) and "[type=" not in str(err)


def test_largest_seed_round_trips_through_the_result_file(tmp_path, capsys, monkeypatch):
    """The seed bound is what the file can hold: 2^64 - 1 is written (as netCDF uint64) and
    read back exactly; one more is refused at validation (case seed-beyond-64-bits)."""
    path = tmp_path / "study.toml"
    path.write_text(BASE.replace("workers = 0", "workers = 0\nseed = 18446744073709551615"))
    code, out, err = run_in_process(["run", str(path), "--quiet"], capsys, monkeypatch,
                                    tmp_path)
    assert code == 0, err
    tree = open_result(tmp_path / "out" / "result.nc")
    assert int(tree.attrs["seed"]) == 2**64 - 1
