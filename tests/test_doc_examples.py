"""Every ```toml block in README.md and docs/*.md validates, so the examples cannot rot.

How a block is read (its first line may carry a marker):

- ``# invalid: <why>``: an example of an error; it must FAIL validation (StudyError or
  SceneError), whatever kind of block it is.
- ``# file: <path>``: the content of a file. A scene file (any other name than
  ``pyproject.toml``) is validated as a scene and written at ``<path>`` beside the studies of
  the same page that come after it; ``pyproject.toml`` is only parsed.
- a whole study (``solver`` and ``method``): written to a temporary folder that holds the
  project's ``studies/scenes`` as ``scenes/`` (what the shipped studies name) plus the page's
  ``# file:`` blocks, and loaded with ``uqflow.study.load_study``;
- a fragment (only study keys, e.g. ``[method]`` or ``[[inputs]]``): merged into a minimal
  valid study of the solver its parameters belong to, then loaded the same way (inputs whose
  names no solver has — a page about distributions — are renamed x1, x2, ... for the linear
  analytic model, so their distributions and correlations are still checked);
- anything else is a scene: validated with the ``from_scene`` of the solver its keys name.
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pytest

from test_shipped_studies import to_toml
from uqflow.errors import SceneError, StudyError
from uqflow.solver import get_solver
from uqflow.study import StudySpec, load_study

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md"] + sorted((ROOT / "docs").glob("*.md"))
SCENES = ROOT / "studies" / "scenes"
MPM_SCENE = "scenes/mpm_contact_thin_small.toml"
BLOCK = re.compile(r"^```toml[ \t]*\n(.*?)^```", re.S | re.M)
STUDY_KEYS = set(StudySpec.model_fields)


@dataclass
class Block:
    page: Path
    line: int
    text: str

    @property
    def marker(self) -> tuple[str, str]:
        first = self.text.lstrip().splitlines()[0] if self.text.strip() else ""
        match = re.match(r"#\s*(invalid|file):\s*(\S.*)", first)
        return (match.group(1), match.group(2).strip()) if match else ("", "")

    @property
    def id(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def blocks() -> list[Block]:
    out = []
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for match in BLOCK.finditer(text):
            out.append(Block(page, text.count("\n", 0, match.start()) + 1, match.group(1)))
    return out


BLOCKS = blocks()


# ----------------------------------------------------------------------------- solvers
def _mpm_scene() -> dict:
    with open(SCENES.parent / MPM_SCENE, "rb") as fh:
        return tomllib.load(fh)


def scene_solver(scene: dict) -> str:
    """The solver whose scene keys these are."""
    if "model" in scene:
        return "analytic"
    if {"domain", "bodies", "cell_size", "snapshots"} & set(scene):
        return "mpm"
    return "gamut_bar"


def _parameters(solver: str, scene) -> set[str]:
    if isinstance(scene, str):
        with open(SCENES.parent / scene, "rb") as fh:
            scene = tomllib.load(fh)
    return set(get_solver(solver).from_scene(scene).nominal())


BASES = {
    "analytic": {"scene": {"model": "ishigami", "a": 7.0, "b": 0.1},
                 "inputs": [{"name": f"x{i}", "distribution": "uniform",
                             "lower": -3.141592653589793, "upper": 3.141592653589793}
                            for i in (1, 2, 3)],
                 "method": {"kind": "monte-carlo", "samples": 64}},
    "gamut_bar": {"scene": {"material": "M1", "local_bonds": 50},
                  "method": {"kind": "nominal"}},
    "mpm": {"scene": MPM_SCENE,
            "inputs": [{"name": "steel.jc.A", "distribution": "normal", "mean": 792e6,
                        "cv": 0.1},
                       {"name": "steel.jc.B", "distribution": "normal", "mean": 510e6,
                        "cv": 0.1}],
            "method": {"kind": "taylor", "order": 1}},
}


def _fragment_solver(data: dict) -> str:
    if "solver" in data:
        return data["solver"]
    if isinstance(data.get("scene"), dict):
        return scene_solver(data["scene"])
    if isinstance(data.get("scene"), str):
        with open(SCENES.parent / data["scene"], "rb") as fh:
            return scene_solver(tomllib.load(fh))
    names = {i.get("name") for i in data.get("inputs", [])}
    names |= set(data.get("correlation", {}).get("inputs", []))
    for f in data.get("fields", []):
        names |= set(f.get("parameters", [f.get("name")]))
    if not names:
        return "analytic"
    for solver in ("analytic", "gamut_bar", "mpm"):
        if names <= _parameters(solver, BASES[solver]["scene"]):
            return solver
    return "linear"          # names no solver has: renamed for the linear analytic model


def merged(data: dict) -> dict:
    """A minimal valid study of the fragment's solver with the fragment's tables in it."""
    solver = _fragment_solver(data)
    if solver == "linear":
        rename = {}
        for i in data.get("inputs", []):
            rename[i["name"]] = f"x{len(rename) + 1}"
        data = dict(data, inputs=[dict(i, name=rename[i["name"]]) for i in data["inputs"]])
        if "correlation" in data:
            data["correlation"] = dict(data["correlation"], inputs=[
                rename[n] for n in data["correlation"]["inputs"]])
        study = {"scene": {"model": "linear", "coefficients": [1.0] * len(rename)},
                 "method": {"kind": "monte-carlo", "samples": 64}}
        solver = "analytic"
    else:
        study = dict(BASES[solver])
    study = {"name": "doc-example", "solver": solver, **study}
    if "inputs" in data or "fields" in data:
        study.pop("inputs", None)        # the fragment's own uncertain parameters
    elif "scene" in data and solver == "analytic":
        # another model: one input per parameter of that model
        study["inputs"] = [{"name": n, "distribution": "normal", "mean": v, "std": 1.0}
                           for n, v in get_solver(solver).from_scene(data["scene"])
                           .nominal().items()]
    if isinstance(data.get("scene"), dict) and isinstance(study["scene"], str):
        data = dict(data, scene={**_mpm_scene(), **data["scene"]})
    study.update(data)
    if study["method"]["kind"] == "kl-weibull" and not study.get("fields"):
        study["method"] = BASES[solver]["method"] if solver != "analytic" else \
            {"kind": "monte-carlo", "samples": 64}
    return study


# ----------------------------------------------------------------------------- validation
def _folder(tmp: Path, block: Block) -> Path:
    (tmp / "scenes").mkdir()
    for scene in SCENES.glob("*.toml"):
        (tmp / "scenes" / scene.name).write_bytes(scene.read_bytes())
    for earlier in BLOCKS:               # the page's scene files, as the page shows them
        kind, name = earlier.marker
        if earlier.page == block.page and earlier.line < block.line and kind == "file" \
                and name != "pyproject.toml":
            (tmp / name).parent.mkdir(parents=True, exist_ok=True)
            (tmp / name).write_text(earlier.text, encoding="utf-8")
    return tmp


def validate(block: Block, tmp: Path, monkeypatch) -> None:
    """Raise StudyError/SceneError (or a TOML error) if the block does not validate."""
    monkeypatch.chdir(tmp)               # a scene's relative directories land in tmp
    kind, name = block.marker
    data = tomllib.loads(block.text)
    if kind == "file" and name == "pyproject.toml":
        return
    if kind == "file" or not set(data) <= STUDY_KEYS:
        get_solver(scene_solver(data)).from_scene(data)
        return
    folder = _folder(tmp, block)
    study = folder / "study.toml"
    if "solver" in data and "method" in data:
        study.write_text(block.text, encoding="utf-8")
    else:
        study.write_text(to_toml(merged(data)) + "\n", encoding="utf-8")
    load_study(study)


def test_the_pages_have_toml_examples():
    assert len(BLOCKS) >= 20
    assert {b.page.name for b in BLOCKS} >= {"README.md", "study-files.md", "fields.md"}


@pytest.mark.parametrize("block", BLOCKS, ids=[b.id for b in BLOCKS])
def test_doc_toml_block_validates(block, tmp_path, monkeypatch):
    if block.marker[0] == "invalid":
        with pytest.raises((StudyError, SceneError, tomllib.TOMLDecodeError)):
            validate(block, tmp_path, monkeypatch)
    else:
        validate(block, tmp_path, monkeypatch)


def test_an_invalid_block_must_fail(tmp_path, monkeypatch):
    """The check itself can fail: a copy of a valid block with a wrong option is caught."""
    good = next(b for b in BLOCKS if b.page.name == "sobol.md")
    bad = Block(good.page, good.line, good.text.replace("samples = 1024", "samples = -3"))
    assert bad.text != good.text
    for name in ("good", "bad"):
        (tmp_path / name).mkdir()
    validate(good, tmp_path / "good", monkeypatch)
    with pytest.raises(StudyError):
        validate(bad, tmp_path / "bad", monkeypatch)


# ----------------------------------------------------------------------------- method options
METHODS_PAGE = ROOT / "docs" / "study-files.md"
SECTION = re.compile(r'^### `kind = "([a-z-]+)"`[^\n]*\n(.*?)(?=^##)', re.S | re.M)
ROW = re.compile(r"^\| `([a-z_0-9]+)` \| ([^|]+) \|", re.M)


def documented_options() -> dict[str, dict[str, str]]:
    """Per method kind in docs/study-files.md: option -> default as the table writes it."""
    text = METHODS_PAGE.read_text(encoding="utf-8")
    return {kind: {name: default.strip().strip("`") for name, default in ROW.findall(body)}
            for kind, body in SECTION.findall(text)}


def _shown_default(field) -> str:
    value = field.default_factory() if field.default_factory is not None else field.default
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    return str(value)


def test_every_method_has_its_options_documented_with_their_defaults():
    from uqflow.methods import get_method
    with open(ROOT / "pyproject.toml", "rb") as fh:     # the project's own methods
        kinds = tomllib.load(fh)["project"]["entry-points"]["uqflow.methods"]
    docs = documented_options()
    assert len(kinds) >= 5
    for kind in kinds:
        assert kind in docs, f"docs/study-files.md has no section for kind = \"{kind}\""
        fields = get_method(kind).Options.model_fields
        assert set(docs[kind]) == set(fields), (kind, sorted(docs[kind]), sorted(fields))
        for name, field in fields.items():
            assert docs[kind][name] == _shown_default(field), (kind, name)


def test_fields_page_tables_match_the_code():
    """docs/fields.md: the kl-weibull options table and the [[fields]] keys with their defaults."""
    from uqflow.fields import FieldSpec, GermSpec
    from uqflow.methods import get_method
    text = (ROOT / "docs" / "fields.md").read_text(encoding="utf-8")
    method_table = text[text.index("## The `kl-weibull` method"):]
    rows = dict(ROW.findall(method_table.split("\n\n### ", 1)[0]))
    fields = get_method("kl-weibull").Options.model_fields
    assert set(rows) == set(fields)
    for name, field in fields.items():
        assert rows[name].strip().strip("`") == _shown_default(field), name

    keys = text[text.index("## Keys of a `[[fields]]` table"):].split("\n\n", 2)[1]
    documented = {}
    for key_cell, default in re.findall(r"^\| ([^|]+) \| ([^|]+) \|", keys, re.M)[1:]:
        names = re.findall(r"`([a-z_.]+)`", key_cell)
        values = [v.strip().strip("`") for v in default.split(",")] \
            if len(names) > 1 else [default.strip().strip("`")]
        documented.update(zip(names, values))
    spec = {**{k: v for k, v in FieldSpec.model_fields.items() if k != "germ"},
            **{f"germ.{k}": v for k, v in GermSpec.model_fields.items()}}
    assert set(documented) == set(spec)
    for name, field in spec.items():
        shown = documented[name]
        if field.is_required():
            assert shown == "required", name
        elif field.default is None:           # derived defaults, written as words
            assert shown == "—" or " if " in shown or shown == "[name]", (name, shown)
        else:
            assert shown.split(" if ")[0] == _shown_default(field), (name, shown)
