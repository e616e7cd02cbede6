"""``uqflow validate`` over several files, random fields in its line, and TOML files with a
UTF-8 byte-order mark (issue 16, Found 2, 4 and 6)."""

import subprocess
import sys
from pathlib import Path

from uqflow.study import load_study

from .test_field_studies import bar_study

UQFLOW = Path(sys.executable).with_name("uqflow")  # the console script of this environment
BOM = "\ufeff"


def test_validate_checks_every_file_one_line_each_and_exit_2_if_any_failed(write_study,
                                                                          tmp_path):
    good = write_study(name="good")
    good.write_text(BOM + good.read_text(encoding="utf-8"), encoding="utf-8")  # also accepted
    bad = write_study(name="bad", method='kind = "monte-carlo"\nsamples = -3')
    missing = tmp_path / "missing.toml"
    fields = bar_study(tmp_path, name="bar")
    done = subprocess.run([str(UQFLOW), "validate", bad, good, missing, fields],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 2
    assert done.stdout.splitlines() == [
        f"{good}: ok (analytic, monte-carlo, 3 random inputs, outputs y)",
        f"{fields}: ok (analytic, kl-weibull, 0 random inputs, 1 random field (E), "
        f"outputs end_displacement)"]
    errors = done.stderr.splitlines()
    assert len(errors) == 2, done.stderr
    assert errors[0].startswith(f"uqflow: error: {bad}: method.samples: ")
    assert errors[1] == f"uqflow: error: {missing}: file not found"


def test_a_byte_order_mark_is_accepted_in_study_and_scene_files(write_study, tmp_path):
    scene = tmp_path / "scene.toml"
    scene.write_text(BOM + 'model = "ishigami"\n', encoding="utf-8")
    study = write_study(scene='"scene.toml"')
    study.write_text(BOM + study.read_text(encoding="utf-8"), encoding="utf-8")
    loaded = load_study(study)
    assert loaded.scene["model"] == "ishigami" and len(loaded.space) == 3
    assert not loaded.text.startswith(BOM)
    # the text without its mark: the same provenance as the file without one
    plain = write_study(name="plain", scene='"scene.toml"')
    assert loaded.text == load_study(plain).text.replace('"plain"', '"s"') \
        .replace("out/plain.nc", "out/s.nc")
