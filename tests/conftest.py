import tomllib
from pathlib import Path

import pytest

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="session")
def reference():
    """Exact answers for the analytic models (copied from shared/reference)."""
    with open(DATA / "uq_test_values.toml", "rb") as f:
        return tomllib.load(f)
