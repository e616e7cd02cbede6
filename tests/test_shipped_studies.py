"""Every study file the project ships validates, and runs to the exit code its header states.

A study that does not end with exit 0 says why in its first line, in the fixed form

    # expect: exit <code> — <why>

and a study without that line must exit 0. ``test_shipped_study_runs_to_its_exit_code`` runs
each one through the CLI at reduced size (``shrunk``: fewer samples or realizations, a
coarser MPM scene; in this process, no figures), so the files as
shipped cannot drift from what the code accepts and does.
"""

from __future__ import annotations

import json
import math
import re
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from uqflow.cli import main
from uqflow.study import load_study

ROOT = Path(__file__).resolve().parent.parent
STUDIES = ROOT / "studies"
FILES = sorted(p for p in STUDIES.rglob("*.toml") if "scenes" not in p.parts)
IDS = [str(p.relative_to(STUDIES)) for p in FILES]
EXPECT = re.compile(r"#\s*expect:\s*exit\s+(\d+)\s+—\s+\S")

# What a reduced run keeps: enough realizations for every statistic a method reports (sample
# variance, a Sobol' bootstrap, the kl-weibull spread); an MPM scene with the same physics on
# a coarser grid (a quarter of the cells per axis). A gamut-bar scene keeps its grid, whose
# outcome (a bar that breaks or not) depends on it, and its amplitude range; a cyclic one
# steps through fewer levels of that range. Its first realizations are those of the full
# study, so the reduced run meets the bars the shipped one does.
SHRUNK_COUNTS = {"samples": 16, "realizations": 2, "min_samples": 8, "trace_points": 4,
                 "resamples": 50, "pilot": 4,
                 # reliability (issue 18): a FORM/SORM search of a few rounds (unconverged
                 # is a warning, not an error), subset levels of two Markov chains, two
                 # cross-entropy rounds
                 "max_iterations": 2, "samples_per_level": 20, "max_levels": 3,
                 "max_rounds": 2}
# A study with fidelity levels keeps its two coarsest (the methods need two): the coupling,
# allocation and estimators run as shipped, without the finest level's cost.
SHRUNK_LEVELS = 2
MPM_RESOLUTION_FACTOR = 0.25
GAMUT_BAR_CYCLES = 3      # the fewest levels whose loops still fit n' and K' with a margin
SPH_STEPS = 8              # load steps of an sph tension scene (each a solve)


def expected_exit(path: Path) -> int:
    """The exit code the study's first line promises (0 without an ``# expect:`` line)."""
    first = path.read_text(encoding="utf-8").splitlines()[0]
    if first.lstrip().startswith("# expect:"):
        match = EXPECT.match(first.strip())
        assert match, f"{path}: malformed first line {first!r} (form: # expect: exit N — why)"
        return int(match.group(1))
    return 0


# ----------------------------------------------------------------------------- TOML writing
def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        if isinstance(value, float) and not math.isfinite(value):
            return "inf" if value > 0 else ("-inf" if value < 0 else "nan")
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{_toml_key(k)} = {_toml_value(v)}"
                                for k, v in value.items()) + " }"
    raise TypeError(f"no TOML form for {value!r}")


def _toml_key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else _toml_value(key)


def to_toml(data: dict, _prefix: str = "") -> str:
    """TOML text of a parsed document: scalars and inline values first, then tables, then
    arrays of tables (enough for study and scene files; tomllib reads it back equal)."""
    lines, tables = [], []
    for key, value in data.items():
        if isinstance(value, dict) and value and not _prefix + key == "scene":
            tables.append((key, value, False))
        elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
            tables.append((key, value, True))
        else:
            lines.append(f"{_toml_key(key)} = {_toml_value(value)}")
    for key, value, is_array in tables:
        name = f"{_prefix}{_toml_key(key)}"
        for item in (value if is_array else [value]):
            lines.append("")
            lines.append(f"[[{name}]]" if is_array else f"[{name}]")
            lines.append(to_toml(item, name + "."))
    return "\n".join(lines)


# ----------------------------------------------------------------------------- shrinking
def _shrink_scene(scene: dict, solver: str) -> dict:
    scene = dict(scene)
    if solver == "mpm":
        scene["resolution"] = scene.get("resolution", 1.0) * MPM_RESOLUTION_FACTOR
    elif solver == "sph" and scene.get("loading", "tension") == "tension":
        scene["steps"] = min(scene.get("steps", 1), SPH_STEPS)
    elif solver == "gamut_bar" and scene.get("loading") == "cyclic":
        scene["cycles"] = min(scene.get("cycles", 10), GAMUT_BAR_CYCLES)
    return scene


def shrunk(path: Path, folder: Path) -> Path:
    """A copy of study ``path`` in ``folder`` at reduced size: the method's counts capped by
    SHRUNK_COUNTS, the scene shrunk (an MPM scene file is copied beside it, shrunk), the
    output in ``folder``, run in this process. Returns the copy's path."""
    with open(path, "rb") as fh:
        data = tomllib.load(fh)
    method = data.get("method", {})
    for key, cap in SHRUNK_COUNTS.items():
        if isinstance(method.get(key), int):
            method[key] = min(method[key], cap)
    if "min_samples" in method and "samples" in method:
        method["min_samples"] = min(method["min_samples"], method["samples"])
    levels = data.get("levels")
    if levels and isinstance(levels.get("values"), list):
        levels["values"] = levels["values"][:SHRUNK_LEVELS]
        method["pilot"] = min(method.get("pilot", SHRUNK_COUNTS["pilot"]), SHRUNK_COUNTS["pilot"])
        method["max_rounds"] = 0             # the pilot alone
        if isinstance(method.get("costs"), list):
            method["costs"] = method["costs"][:SHRUNK_LEVELS]
    scene = data.get("scene")
    if levels:
        # the levels set the resolution; the scene file is read where it is
        data["scene"] = str((path.parent / scene).resolve()) if isinstance(scene, str) else scene
    elif isinstance(scene, str):
        with open(path.parent / scene, "rb") as fh:
            scene_data = tomllib.load(fh)
        scene_file = folder / f"scene_{path.stem}.toml"
        scene_file.write_text(to_toml(_shrink_scene(scene_data, data["solver"])) + "\n",
                              encoding="utf-8")
        data["scene"] = scene_file.name
    elif isinstance(scene, dict):
        data["scene"] = _shrink_scene(scene, data["solver"])
    execution = data.setdefault("execution", {})
    execution["workers"] = 0
    execution.pop("scheduler", None)
    output = data.setdefault("output", {})
    output["path"] = f"{path.stem}.nc"
    output["figures"] = False
    copy = folder / path.name
    copy.write_text(to_toml(data) + "\n", encoding="utf-8")
    return copy


# ----------------------------------------------------------------------------- tests
def test_the_studies_folder_is_found():
    assert len(FILES) >= 25


@pytest.mark.parametrize("path", FILES, ids=IDS)
def test_shipped_study_validates(path):
    study = load_study(path)
    assert study.outputs
    assert study.output_path.suffix == ".nc"


@pytest.mark.parametrize("path", FILES, ids=IDS)
def test_shrunk_copy_keeps_the_study(path, tmp_path):
    """The reduced copy is the same study (solver, inputs, fields, method kind) with smaller
    counts: what the run test exercises is what ships."""
    original, copy = load_study(path), load_study(shrunk(path, tmp_path))
    assert copy.spec.solver == original.spec.solver
    assert copy.spec.method.kind == original.spec.method.kind
    assert [i.name for i in copy.spec.inputs] == [i.name for i in original.spec.inputs]
    assert copy.outputs == original.outputs
    assert copy.output_path.parent == tmp_path


def test_expect_lines_are_read():
    assert EXPECT.match("# expect: exit 1 — the bar breaks")
    assert not EXPECT.match("# expect: exit one — why")
    assert all(expected_exit(p) in (0, 1, 2) for p in FILES)


# ----------------------------------------------------------------------------- bit for bit
# Digests of every statistics variable of each shipped study run as ``shrunk`` makes it, recorded
# at the revision before the issue-17 redesign (tools/shipped_statistics.py; the file says the
# revision, the command and the machine). A refactoring that moves code keeps every bit; a
# change that means to change numbers re-records the file and says why in its commit.
REFERENCE = Path(__file__).resolve().parent / "data" / "shipped_statistics.json"
# The costs of a level study without stated costs are its measured wall times, and what
# derives from them (the allocation's cost ratio): they differ from run to run by design.
MEASURED_COST_UNITS = "s"
# Folders of studies added after the digests were recorded: no revision before the redesign
# ran them, so there is nothing to compare bit for bit; they must still run to their exit code.
ADDED_AFTER_RECORDING = ("reliability/",)


def _digest_tool():
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import shipped_statistics
    finally:
        sys.path.pop(0)
    return shipped_statistics


def _measured(name: str, stats_path: Path) -> bool:
    import xarray as xr

    with xr.open_datatree(stats_path) as tree:
        stats = tree["statistics"].to_dataset()
        measured = [v for v in ("level_run_cost", "model_run_cost")
                    if v in stats and stats[v].attrs.get("units") == MEASURED_COST_UNITS]
    return bool(measured) and "cost" in name


def assert_statistics_as_recorded(name: str, result: Path) -> None:
    """Every statistics variable recorded for study ``name`` has the same bits in ``result``
    (variables added since are allowed; one missing or changed is named)."""
    reference = json.loads(REFERENCE.read_text(encoding="utf-8"))
    tool = _digest_tool()
    if reference["machine"] != tool.machine():
        pytest.skip(f"statistics digests were recorded on {reference['machine']}, this is "
                    f"{tool.machine()}: re-record them with: {reference['command']}")
    recorded = reference["studies"].get(name)
    assert recorded is not None, f"{name}: no recorded digests (re-record: " \
                                 f"{reference['command']})"
    now = tool.statistics_digests(result)
    missing = sorted(set(recorded) - set(now))
    changed = sorted(v for v in recorded if v in now and now[v] != recorded[v]
                     and not _measured(v, result))
    assert not missing and not changed, (
        f"{name}: statistics differ from revision {reference['revision']}: missing "
        f"{missing}, changed {changed}")


def test_digests_tell_a_one_ulp_change():
    tool = _digest_tool()
    x = np.linspace(0.0, 1.0, 7)
    assert tool.variable_digest(x, ("t",)) != tool.variable_digest(
        np.nextafter(x, 2.0), ("t",))
    assert tool.variable_digest(x, ("t",)) != tool.variable_digest(x, ("s",))
    assert tool.variable_digest(x, ("t",)) == tool.variable_digest(x.copy(), ("t",))


@pytest.mark.slow
@pytest.mark.parametrize("path", FILES, ids=IDS)
def test_shipped_study_runs_to_its_exit_code(path, tmp_path, capsys):
    """... and, where it finishes, gives the statistics recorded before the redesign, bit
    for bit."""
    code = main(["run", str(shrunk(path, tmp_path)), "--quiet", "--no-figures"])
    err = capsys.readouterr().err
    assert code == expected_exit(path), err
    if code == 0:
        result = tmp_path / f"{path.stem}.nc"
        assert result.is_file()
        name = path.relative_to(STUDIES).as_posix()
        if not name.startswith(ADDED_AFTER_RECORDING):
            assert_statistics_as_recorded(name, result)
