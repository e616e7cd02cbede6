"""The typed SPH scene (solvers/sph/scene.py): every shipped scene resolves to the Config the
hand-written parser gave it, and a bad key is a one-line error naming the file and the key."""

import json
import re
import tomllib
from pathlib import Path

import pytest

from solvers.sph.scene import SceneSpec, parse
from uqflow.errors import SceneError, StudyError
from uqflow.study import load_study

REPO = Path(__file__).resolve().parents[3]
#: repr(Config) of every shipped SPH scene as the hand-written parser (solvers/sph/scene.py
#: before pydantic) resolved it; repr writes each float exactly (shortest round trip), so
#: equal text is the same value to the bit. Until commit b8d12a2 both parsers were kept and
#: compared here, also on ~1,900 mutants of these scenes (the same Config, or refused naming
#: the same key; the old one alone raised OverflowError on integers just below 2^1024)
RECORDED = Path(__file__).parent / "data" / "shipped_scene_configs.json"


def shipped_scenes() -> dict[str, dict]:
    """Every SPH scene the project ships: the scene files, and inline scenes of SPH studies."""
    found = {}
    for path in sorted((REPO / "studies").rglob("*.toml")):
        doc = tomllib.loads(path.read_text())
        name = str(path.relative_to(REPO))
        if path.parent.name == "scenes" and path.name.startswith("sph_"):
            found[name] = doc
        elif doc.get("solver") == "sph" and isinstance(doc.get("scene"), dict):
            found[f"{name}:scene"] = doc["scene"]
    return found


SHIPPED = shipped_scenes()


def test_every_shipped_scene_resolves_to_the_config_the_old_parser_gave():
    recorded = json.loads(RECORDED.read_text())
    assert sorted(SHIPPED) == sorted(recorded), "a shipped SPH scene is not recorded"
    for name, scene in SHIPPED.items():
        assert repr(parse(scene)) == recorded[name], name


def _write_study(tmp_path, scene_lines: str, inline: bool = False) -> Path:
    study = tmp_path / "study.toml"
    head = 'name = "t"\nsolver = "sph"\n[method]\nkind = "nominal"\n'
    if inline:
        study.write_text('name = "t"\nsolver = "sph"\n[scene]\n' + scene_lines +
                         '[method]\nkind = "nominal"\n')
    else:
        (tmp_path / "scene.toml").write_text(scene_lines)
        study.write_text('scene = "scene.toml"\n' + head)
    return study


EXAMPLE1 = (REPO / "studies" / "scenes" / "sph_example1.toml").read_text()


@pytest.mark.parametrize("edit, key, reason", [
    (("nu = 0.33", "nu = 0.5"), "scene.matrix.nu", "less than 0.5"),
    (("E = 900.0", "E = true"), "scene.matrix.E", "must be a finite number, got True"),
    (("spacing = 2.0", "spacing = 2.0\ncolour = 1"), "scene.colour", "unknown key"),
    (("layout = \"polar\"", "layout = \"hexagonal\""), "scene.layout", "'regular', 'polar'"),
    (("semi_axes = [20.0, 20.0]", "semi_axes = [20.0, -1.0]"), "scene.inclusions[0].semi_axes",
     "must be > 0"),
    (("constraints = \"master-slave\"", "constraints = \"master-slave\"\npenalty = 1e4"),
     "scene.penalty", "applies only to constraints = \"penalty\""),
    (("outer_radius = 60.0", "outer_radius = 10.0"), "scene.inclusions[0].semi_axes",
     "not inside the disc"),
])
def test_a_bad_scene_file_is_one_line_naming_the_scene_file_and_the_key(tmp_path, edit, key,
                                                                        reason):
    old, new = edit
    assert old in EXAMPLE1
    study = _write_study(tmp_path, EXAMPLE1.replace(old, new, 1))
    with pytest.raises(SceneError) as caught:
        load_study(study)
    exc = caught.value
    assert (exc.file, exc.key) == (str(tmp_path / "scene.toml"), key), str(exc)
    assert reason in exc.reason and "\n" not in str(exc)


def test_an_unknown_key_names_the_key_it_resembles(tmp_path):
    study = _write_study(tmp_path, EXAMPLE1.replace("eigenstrain_mode", "eigenstrain_mod", 1))
    with pytest.raises(SceneError, match=r"scene.eigenstrain_mod: unknown key \(did you mean "
                                         r"'eigenstrain_mode'\?\)"):
        load_study(study)


def test_a_bad_inline_scene_names_the_study_file(tmp_path):
    study = _write_study(tmp_path, EXAMPLE1.replace("eigenstrain = 0.01", "eigenstrain = 0.6"),
                         inline=True)
    with pytest.raises(StudyError) as caught:
        load_study(study)
    assert (caught.value.file, caught.value.key) == (str(study), "scene.eigenstrain")


def test_a_size_the_layout_does_not_use_is_still_checked():
    # the hand-written parser ignored width and height of a polar scene whatever they held
    scene = tomllib.loads(EXAMPLE1)
    assert repr(parse(scene)) == repr(parse({**scene, "width": 3.0}))
    with pytest.raises(SceneError) as caught:
        parse({**scene, "width": "wide"})
    assert caught.value.key == "scene.width"


def test_the_declared_keys_are_the_documented_ones():
    doc = (REPO / "docs" / "sph.md").read_text()
    keys = doc[doc.index("## 12. Scene keys"):]
    missing = [key for key in SceneSpec.model_fields
               if not re.search(rf"`{re.escape(key)}(`| = )", keys)]
    assert not missing, f"docs/sph.md does not describe {missing}"
