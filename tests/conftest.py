import importlib.util
import tomllib
from pathlib import Path

import pytest

DATA = Path(__file__).parent / "data"
BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture(scope="session")
def reference():
    """Exact answers for the analytic models (copied from shared/reference)."""
    with open(DATA / "uq_test_values.toml", "rb") as f:
        return tomllib.load(f)


@pytest.fixture(scope="session")
def benchmark_module():
    """``load(name)``: the script ``benchmarks/<name>.py`` imported as a module (the folder
    is no package a test could import from)."""

    def load(name):
        spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module

    return load
