"""``--set key=value``: study keys overridden from the command line and the Python API,
validated like the file, recorded in the result's provenance (issue 17, point 3)."""

import subprocess
import sys
from pathlib import Path

import pytest
import xarray as xr

import uqflow
from uqflow.errors import StudyError
from uqflow.layout import STUDY_HASH, STUDY_OVERRIDES, STUDY_TEXT
from uqflow.study import load_study, parse_override, read_overrides, set_key, toml_value

from ._common import comparable

UQFLOW = Path(sys.executable).with_name("uqflow")  # the console script of this environment
PLAIN_MC = 'kind = "monte-carlo"\nsamples = 256'


def cli(*args):
    return subprocess.run([str(UQFLOW), *map(str, args)], capture_output=True, text=True,
                          timeout=300)


@pytest.mark.parametrize("text, expected", [
    ("method.samples=64", ("method.samples", 64)),
    ("inputs.0.cv = 0.2", ("inputs.0.cv", 0.2)),
    ('method.rule="lhs"', ("method.rule", "lhs")),
    ("method.rule=lhs", ("method.rule", "lhs")),  # a bare word is a string
    ("output.figures=true", ("output.figures", True)),
    ("scene.a=[1, 2]", ("scene.a", [1, 2])),
    ("scene={ model = \"ishigami\" }", ("scene", {"model": "ishigami"})),
    ("name=a=b", ("name", "a=b")),
    ("method.samples=1e", ("method.samples", "1e")),  # not a TOML number: a string
    ('description="tab\\t, DEL \\u007f, \\u00fc"', ("description", "tab\t, DEL \x7f, \u00fc")),
])
def test_a_set_value_is_read_as_a_toml_value(text, expected):
    assert parse_override(text) == expected
    key, value = expected
    assert parse_override(f"{key}={toml_value(value)}") == expected  # as recorded


@pytest.mark.parametrize("text", ["method.samples", "=64", ""])
def test_a_set_without_key_and_value_is_refused_naming_set(text):
    with pytest.raises(StudyError, match=r"^--set: expected KEY=VALUE"):
        parse_override(text)


def test_overrides_give_the_statistics_of_the_file_that_says_the_same(write_study, tmp_path):
    """method.samples and method.rule set from outside: the same runs and statistics, bit for
    bit, as a study file that writes them; the result records the overrides and keeps the
    file's own text."""
    base = write_study(name="s", method=PLAIN_MC)
    study = load_study(base, overrides={"method.samples": 64, "method.rule": "lhs"})
    assert study.method.options.samples == 64 and study.method.options.rule == "lhs"
    overridden = uqflow.run_study(study, show_progress=False)

    (tmp_path / "written").mkdir()
    written = write_study(name="s", method='kind = "monte-carlo"\nsamples = 64\nrule = "lhs"',
                          filename="written/s.toml")
    plain = uqflow.run_study(load_study(written), show_progress=False)
    runs_a, stats_a = comparable(overridden.path)
    runs_b, stats_b = comparable(plain.path)
    assert runs_a.sizes["realization"] == 64
    xr.testing.assert_identical(stats_a, stats_b)
    xr.testing.assert_identical(runs_a, runs_b)

    attrs = uqflow.open_result(overridden.path).attrs
    assert attrs[STUDY_OVERRIDES] == 'method.samples = 64\nmethod.rule = "lhs"\n'
    assert read_overrides(attrs[STUDY_OVERRIDES]) == {"method.samples": 64, "method.rule": "lhs"}
    assert attrs[STUDY_TEXT] == base.read_text()
    assert STUDY_OVERRIDES not in uqflow.open_result(plain.path).attrs
    assert attrs[STUDY_HASH] != load_study(base).sha256  # the hash covers the overrides


def test_entries_of_an_array_of_tables_are_set_by_index(write_study):
    path = write_study()
    for key in ("inputs.1.upper", "inputs[1].upper"):
        study = load_study(path, overrides={key: 2.0})
        assert study.spec.inputs[1].upper == 2.0 and study.spec.inputs[0].upper > 3
        # the mean of U(-pi, 2), (2 - pi) / 2, to the rounding of its few operations
        assert study.space.means[1] == pytest.approx((2.0 - 3.141592653589793) / 2, rel=1e-14)
    with pytest.raises(StudyError) as caught:
        load_study(path, overrides={"inputs.3.upper": 2.0})
    assert str(caught.value) == (f"{path}: --set: inputs.3.upper: inputs has 3 entries (0 to "
                                 f"2); --set sets keys of an entry by its index, it adds none")


def test_a_missing_table_is_created_and_a_scene_file_is_reached(write_study, tmp_path):
    path = write_study()
    study = load_study(path, overrides={"correlation.inputs": ["x1", "x2"],
                                        "correlation.matrix": [[1.0, 0.5], [0.5, 1.0]]})
    assert study.space.correlation[0, 1] == 0.5 and study.space.correlation[0, 2] == 0.0
    (tmp_path / "scene.toml").write_text('model = "ishigami"\na = 7.0\n')
    from_file = write_study(name="f", scene='"scene.toml"')
    study = load_study(from_file, overrides={"scene.a": 3.5})
    y = study.solver.run({"x1": 0.0, "x2": 1.5707963267948966, "x3": 0.0})["y"].item()
    # y = a sin^2(pi/2): sin within an ulp of 1 (libm), squared and scaled: 3 roundings
    assert study.scene["a"] == 3.5 and y == pytest.approx(3.5, rel=5e-16)
    with pytest.raises(StudyError, match=r"scene\.toml: scene\.a: .*\(from --set scene\.a=\"x\"\)"):
        load_study(from_file, overrides={"scene.a": "x"})


def test_a_bad_override_is_refused_in_one_line_naming_file_key_and_set(write_study):
    path = write_study(method=PLAIN_MC)
    done = cli("run", path, "--set", "method.samples=-3")
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.count("\n") == 1, done.stderr
    assert done.stderr.startswith(f"uqflow: error: {path}: method.samples: ")
    assert done.stderr.rstrip().endswith("(from --set method.samples=-3)")
    assert not (path.parent / "out").exists()  # nothing written


def test_an_unknown_key_is_refused_with_its_close_match(write_study):
    path = write_study(method=PLAIN_MC)
    done = cli("validate", path, "--set", "method.sampels=64")
    assert done.returncode == 2
    assert done.stderr == (f"uqflow: error: {path}: method.sampels: unknown key (did you mean "
                           f"'samples'?) (from --set method.sampels=64)\n")
    with pytest.raises(StudyError, match=r"execution\.wrokers: unknown key .*--set"):
        load_study(path, overrides={"execution.wrokers": 1})


def test_a_key_below_a_value_is_refused(write_study):
    path = write_study(method=PLAIN_MC)
    with pytest.raises(StudyError) as caught:
        load_study(path, overrides={"method.samples.x": 1})
    assert str(caught.value) == (f"{path}: --set: method.samples.x: method.samples is 256, "
                                 f"not a table")


def test_validate_applies_the_overrides_to_every_file(write_study):
    a = write_study(name="a", method=PLAIN_MC)
    b = write_study(name="b", method=PLAIN_MC)
    done = cli("validate", a, b, "--set", "method.kind=pce", "--set", "method.samples=64")
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == [
        f"{a}: ok (analytic, pce, 3 random inputs, outputs y)",
        f"{b}: ok (analytic, pce, 3 random inputs, outputs y)"]


def test_run_with_set_records_the_overrides(write_study):
    path = write_study(method=PLAIN_MC)
    done = cli("run", path, "--quiet", "--set", "method.kind=pce", "--set",
               "method.samples=64")
    assert done.returncode == 0, done.stderr
    tree = uqflow.open_result(path.parent / "out" / "s.nc")
    assert tree.attrs["method"] == "pce"
    assert tree.attrs[STUDY_OVERRIDES] == 'method.kind = "pce"\nmethod.samples = 64\n'
    assert tree["runs"].sizes["realization"] == 64


def test_a_resume_with_other_overrides_is_refused(write_study):
    path = write_study(method=PLAIN_MC)
    result = uqflow.run_study(load_study(path, overrides={"method.samples": 64}),
                              show_progress=False).path
    before = result.read_bytes()
    for other in ({"method.samples": 32}, {}):
        with pytest.raises(StudyError) as caught:
            uqflow.run_study(load_study(path, overrides=other), resume=True,
                             show_progress=False)
        message = str(caught.value)
        assert message.startswith(f"{path}: --set: {result} was made with other --set "
                                  f"overrides (method.samples = 64) than these (")
        assert result.read_bytes() == before  # nothing destroyed
    # the same overrides resume
    again = uqflow.run_study(load_study(path, overrides={"method.samples": 64}), resume=True,
                             show_progress=False)
    assert again.resumed == 64


def test_the_overrides_section_of_the_study_file_page_is_what_uqflow_does():
    """docs/study-files.md, Overrides: its validate command validates, and its error line is
    the one uqflow prints."""
    root = Path(__file__).resolve().parents[2]
    page = (root / "docs" / "study-files.md").read_text(encoding="utf-8")
    section = page.split("## Overrides", 1)[1].split("\n## ", 1)[0]
    command = next(line.split() for line in section.splitlines()
                   if line.strip().startswith("uqflow validate"))
    done = subprocess.run([str(UQFLOW), *command[1:]], capture_output=True, text=True,
                          timeout=300, cwd=root)
    assert done.returncode == 0, done.stderr
    assert done.stdout == "studies/ishigami_mc.toml: ok (analytic, pce, 3 random inputs, " \
                          "outputs y)\n"
    error = next(line.strip() for line in section.splitlines()
                 if line.strip().startswith("uqflow: error:"))
    key_value = error.rsplit("--set ", 1)[1].rstrip(")")
    done = subprocess.run([str(UQFLOW), "validate", "studies/ishigami_mc.toml", "--set",
                           key_value], capture_output=True, text=True, timeout=300, cwd=root)
    assert done.returncode == 2 and done.stderr == error + "\n"


def test_recorded_overrides_read_back_and_set_into_a_table():
    """What a report does to rebuild the scene a result ran: the recorded lines read back
    and set into the table, arrays entered by index, values with ' = ' inside kept whole."""
    overrides = {"scene.bodies.1.material": {"model": "elastic", "E": 2e11},
                 "scene.name": "a = b", "scene.cell_size": 0.5}
    text = "".join(f"{key} = {toml_value(value)}\n" for key, value in overrides.items())
    assert read_overrides(text) == overrides
    scene = {"bodies": [{"material": "steel"}, {"material": "water"}], "cell_size": 1.0}
    for key, value in read_overrides(text).items():
        set_key(scene, key.removeprefix("scene."), value)
    assert scene == {"bodies": [{"material": "steel"}, {"material": {"model": "elastic",
                                                                      "E": 2e11}}],
                     "cell_size": 0.5, "name": "a = b"}
