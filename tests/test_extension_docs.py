"""docs/writing-a-solver.md and docs/writing-a-method.md run as written, and say true numbers.

Every ```python block of a page runs in order in one namespace, in an empty folder; a ```toml
block is written to the file the sentence before it names ("Save this as `x.toml`").
"""

from __future__ import annotations

import math
import re
import sys
import types
from pathlib import Path

import numpy as np
import pytest

DOCS = Path(__file__).resolve().parents[1] / "docs"
_BLOCK = re.compile(r"```(python|toml)\n(.*?)```", re.S)
_SAVE_AS = re.compile(r"Save this as\s+`([^`]+)`:\s*$")


def page_blocks(page: str) -> list[tuple[str, str, str | None]]:
    """(language, code, file to write it to) for every python/toml block of ``page``."""
    text = (DOCS / page).read_text()
    found = []
    for match in _BLOCK.finditer(text):
        before = " ".join(text[:match.start()].rstrip().split("\n\n")[-1].split())  # paragraph
        target = _SAVE_AS.search(before)
        found.append((match.group(1), match.group(2), target.group(1) if target else None))
    return found


def execute_page(page: str, folder: Path, monkeypatch) -> dict:
    """Run the page's blocks in ``folder``; return the Python namespace they leave."""
    monkeypatch.chdir(folder)
    # a module of its own, so that pickle finds the page's classes as it finds a package's
    module = types.ModuleType(f"docs_{Path(page).stem.replace('-', '_')}")
    monkeypatch.setitem(sys.modules, module.__name__, module)
    for language, code, target in page_blocks(page):
        if language == "toml":
            assert target, f"{page}: a toml block without 'Save this as `file`:' before it"
            (folder / target).write_text(code)
        else:
            exec(compile(code, f"{page}", "exec"), module.__dict__)
    return module.__dict__


def test_every_block_of_the_pages_is_run():
    for page, python, toml in (("writing-a-solver.md", 4, 1), ("writing-a-method.md", 3, 1)):
        blocks = page_blocks(page)
        assert [b[0] for b in blocks].count("python") == python
        assert [(b[0], b[2] is not None) for b in blocks].count(("toml", True)) == toml


def test_writing_a_solver_runs_and_its_numbers_hold(tmp_path, monkeypatch):
    ns = execute_page("writing-a-solver.md", tmp_path, monkeypatch)
    text = (DOCS / "writing-a-solver.md").read_text()
    # the closed forms the page states: δ = F L³/(3 E I) = 3.2 mm, σ = F L (h/2)/I = 24 MPa
    inertia = 0.05 * 0.1**3 / 12
    assert "**δ = 3.2 mm**" in text and "**σ = 24 MPa**" in text
    # a handful of roundings of O(1) factors: 1e-14 relative is ~50 ulp
    assert ns["deflection"] == pytest.approx(1000.0 * 2.0**3 / (3 * 200e9 * inertia),
                                             rel=1e-14, abs=0)
    assert ns["deflection"] == pytest.approx(3.2e-3, rel=1e-14, abs=0)
    # σ = F L (h/2)/I: four roundings of O(1) factors, ≤ 1e-15; 1e-14 is ~50 ulp
    assert ns["stress"] == pytest.approx(24e6, rel=1e-14, abs=0)
    assert "I = 4.1667·10⁻⁶ m⁴" in text and round(inertia * 1e6, 4) == 4.1667
    # the study's mean: E[F] L³/(3 I) E[1/E], E[1/E] ≈ (1 + cv²)/μ_E (second order; the
    # next term, 3 cv⁴ ~ 2e-5, is far below the sampling error)
    expected = 1000.0 * 2.0**3 / (3 * inertia) * (1 + 0.05**2) / 200e9
    assert "3.208 mm" in text and round(expected * 1e3, 3) == 3.208
    stderr = 3.2e-3 * math.hypot(0.1, 0.05) / math.sqrt(32)
    assert "0.063 mm" in text and round(stderr * 1e3, 3) == 0.063
    # sampling error of 32 runs: within 4 standard errors (a 6e-5 chance for a normal mean)
    assert abs(ns["mean"] - expected) < 4 * stderr
    assert ns["outcome"].runs["status"].values.tolist() == ["ok"] * 32


def test_writing_a_solver_function_form_keeps_its_array_output(tmp_path, monkeypatch):
    ns = execute_page("writing-a-solver.md", tmp_path, monkeypatch)
    solver = ns["CantileverFunction"].from_scene({"h": 0.12})
    result = solver.run({"F": 2000.0})
    assert result["deflection_line"].dims == ("station",)
    assert result["deflection_line"].attrs == {"units": "m", "long_name": "deflection"}
    inertia = 0.05 * 0.12**3 / 12
    # w(x) = F x² (3L − x)/(6 E I) at x = L/2: a few roundings, 1e-14 relative
    assert float(result["deflection_line"][2]) == pytest.approx(
        2000.0 * 1.0**2 * (6.0 - 1.0) / (6 * 200e9 * inertia), rel=1e-14, abs=0)


def test_writing_a_solver_refuses_a_bad_scene_key(tmp_path, monkeypatch):
    from uqflow.errors import SceneError

    ns = execute_page("writing-a-solver.md", tmp_path, monkeypatch)
    for cls, scene, key in ((ns["Cantilever"], {"depth": 1.0}, "scene.depth"),
                            (ns["Cantilever"], {"height": 0.0}, "scene.height"),
                            (ns["CantileverFunction"], {"G": 1.0}, "scene.G")):
        with pytest.raises(SceneError) as err:
            cls.from_scene(scene)
        assert err.value.key == key and "\n" not in str(err.value)


def test_writing_a_method_runs_and_its_numbers_hold(tmp_path, monkeypatch):
    ns = execute_page("writing-a-method.md", tmp_path, monkeypatch)
    text = (DOCS / "writing-a-method.md").read_text()
    assert "E[y] = 1 + 2·1 − 3 = **0**" in text
    assert "√5 ≈ **2.236**" in text and round(math.sqrt(5), 3) == 2.236
    stats = ns["stats"]
    # the pair averages are exact but for rounding: ≤ a few ulp of |y| ≤ 20
    assert abs(float(stats["y"].sel(statistic="mean"))) < 1e-12
    # std of 64 independent mirrored pairs: relative standard error ≈ 1/√(2·64) ≈ 9 %
    # (stated on the page); four of them bound it (a ~1e-4 chance for a normal sample)
    assert "1/√(2·64) ≈ 9 %" in text and round(100 / math.sqrt(128)) == 9
    std = float(stats["y"].sel(statistic="std"))
    assert abs(std / math.sqrt(5) - 1) < 4 / math.sqrt(128)
    assert stats.attrs["pairs_used"] == 64


def test_the_antithetic_method_drops_a_pair_with_a_failed_run(tmp_path, monkeypatch):
    ns = execute_page("writing-a-method.md", tmp_path, monkeypatch)
    runs = ns["outcome"].runs.copy(deep=True)
    runs["status"].values[3] = "failed"
    runs["y"].values[3] = np.nan
    stats = ns["Antithetic"](pairs=64).analyze(runs, runs)
    assert stats.attrs["pairs_used"] == 63 and stats.attrs["failed_runs"] == 1
    # the 63 remaining pair averages are still exact: the mean stays 0 to rounding
    assert abs(float(stats["y"].sel(statistic="mean"))) < 1e-12


def test_the_antithetic_report_hook_adds_a_column_and_a_description(tmp_path, monkeypatch):
    import uqflow
    from uqflow.report import ResultView

    ns = execute_page("writing-a-method.md", tmp_path, monkeypatch)
    view = ResultView(uqflow.open_result(ns["outcome"].path))
    report = ns["Antithetic"].report(view)
    assert report.description == "antithetic Monte Carlo, 64 pairs of mirrored runs"
    [column] = report.columns
    stderr = float(view.stats["y"].sel(statistic="stderr"))
    assert column.cell("y", {}) == uqflow.report.number(stderr)
