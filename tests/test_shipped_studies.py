"""Every study file the project ships validates: solver, scene, inputs, fields, method."""

from pathlib import Path

import pytest

from uqflow.study import load_study

STUDIES = Path(__file__).resolve().parent.parent / "studies"
FILES = sorted(p for p in STUDIES.rglob("*.toml") if "scenes" not in p.parts)


def test_the_studies_folder_is_found():
    assert len(FILES) >= 25


@pytest.mark.parametrize("path", FILES, ids=[str(p.relative_to(STUDIES)) for p in FILES])
def test_shipped_study_validates(path):
    study = load_study(path)
    assert study.outputs
    assert study.output_path.suffix == ".nc"
