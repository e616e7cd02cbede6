"""The SPH benchmarks in their --quick mode, so they cannot rot (no timing is asserted)."""

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]


def load(name):
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("name", ["sph_scaling", "sph_example3_timing"])
def test_benchmark_runs_in_quick_mode(name, monkeypatch):
    module = load(name)
    monkeypatch.setattr(module, "write_section", lambda *a: pytest.fail("quick mode wrote"))
    assert module.main(["--quick"])
