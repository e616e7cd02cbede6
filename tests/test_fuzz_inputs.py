"""What validates runs; what cannot run does not validate (issue 8, point 9).

Every shipped study, the scene file it reads, and every other shipped scene file (inside a
host study that runs it once) is mutated one value at a time into a
boolean, a string, NaN/inf, a huge, negative or zero number, a float where an integer was, an
array or a table where a scalar was, a missing key or a duplicated key. For each variant
``load_study`` either

- accepts it, and then the method can build its design (``plan``), or
- raises ONE line ``<file>: <key>: <reason>`` naming the file that holds the mutated value (or
  the study, where it names the solver's parameters or outputs) and a key of the mutated
  table or of one that depends on it (``DEPENDENTS``),

and never anything else (no OverflowError, MemoryError, TypeError, no RuntimeWarning). The
shipped studies are first shrunk (few samples, few bootstrap resamples) so that an accepted
variant plans in milliseconds; a mutation into a huge count must then be refused by the
count's bound. ``UQFLOW_FUZZ_MUTANTS=8`` tries 8 mutants per value instead of 1 (about 13,000
variants, a few minutes). The documented limits are checked one above each, and a handful of
variants go through the real ``uqflow`` process: exit 2, one stderr line, nothing written.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from uqflow.errors import StudyError
from uqflow.study import load_study

REPO = Path(__file__).resolve().parents[1]
SHIPPED_STUDIES = sorted((REPO / "studies").glob("*.toml")) + \
    sorted((REPO / "studies" / "gamut_bar").glob("*.toml"))
SCENES = REPO / "studies" / "scenes"


def _scenes_no_study_reads() -> list[Path]:
    read = {(study.parent / scene).resolve() for study in SHIPPED_STUDIES
            if isinstance(scene := tomllib.loads(study.read_text()).get("scene"), str)}
    return [p for p in sorted(SCENES.glob("*.toml")) if p.resolve() not in read]


# Scene files no shipped study reads (verification scenes) are mutated inside a host study
# that runs them once, at their nominal values.
SHIPPED = SHIPPED_STUDIES + _scenes_no_study_reads()


def _base(study: Path) -> dict:
    """The TOML document of a shipped study, or the host study of a lone scene file."""
    if study.parent == SCENES:
        # an SPH scene file under the MPM solver would stop at the MPM parser's first key
        solver = "sph" if study.name.startswith("sph_") else "mpm"
        return {"name": "host", "solver": solver, "scene": str(study),
                "method": {"kind": "nominal"}, "execution": {"workers": 0}}
    return tomllib.loads(study.read_text())

# Sizes an accepted variant may plan with: small, so that a few hundred variants take seconds.
SHRUNK = {"samples": 8, "realizations": 4, "resamples": 10, "min_samples": 4}

MISSING, DUPLICATED = object(), object()
# Mutants tried per leaf: every kind still meets every section of some study (about 1,200
# variants, 20 s on one core).
MUTANTS_PER_LEAF = int(os.environ.get("UQFLOW_FUZZ_MUTANTS", 1))


def _mutants(value):
    """The malformed values one leaf is turned into (bounded by what TOML can write)."""
    out = [True, "2", math.nan, math.inf, -math.inf, 1e300, -1e300, 0, -1,
           2**63 - 1, 10**400, [value], {"value": value}, MISSING, DUPLICATED]
    if isinstance(value, int) and not isinstance(value, bool):
        out += [float(value), value + 0.5]
    if isinstance(value, float):
        out += [1e-300, -value]
    if isinstance(value, str):
        out += ["", " ", "a\x00b"]
    return out


def _leaves(data, path=()):
    """Paths of the scalars (and arrays of scalars) in a TOML document."""
    if isinstance(data, dict):
        for k, v in data.items():
            yield from _leaves(v, path + (k,))
    elif isinstance(data, list) and data and all(isinstance(v, dict) for v in data):
        for i, v in enumerate(data):
            yield from _leaves(v, path + (i,))
    else:
        yield path
        if isinstance(data, list):
            for i, v in enumerate(data):
                if not isinstance(v, (list, dict)):
                    yield path + (i,)


def _key(path) -> str:
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else ("." if out else "") + str(part)
    return out


def _toml_value(v) -> str:
    """``v`` as a TOML value, tables inline; a ``_Dup`` table writes one key twice."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) \
            else repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        pairs = [f"{json.dumps(str(k))} = {_toml_value(x)}" for k, x in v.items()]
        if isinstance(v, _Dup):
            pairs.append(pairs[list(v).index(v.dup)])
        return "{" + ", ".join(pairs) + "}"
    raise TypeError(type(v))


class _Dup(dict):
    """A table whose key ``dup`` is written twice (TOML forbids it)."""

    dup = None


def _shrunk(doc: dict) -> dict:
    method = doc.get("method", {})
    for k, small in SHRUNK.items():
        if isinstance(method.get(k), int):
            method[k] = min(method[k], small)
    return doc


def _mutate(doc, path, new):
    """A deep copy of ``doc`` with the value at ``path`` replaced (or removed, or doubled)."""
    doc = json.loads(json.dumps(doc))
    holder = doc
    for part in path[:-1]:
        holder = holder[part]
    last = path[-1]
    if new is MISSING:
        del holder[last]
    elif new is DUPLICATED:
        if isinstance(holder, list):
            holder.append(holder[last])
        else:
            dup = _Dup(holder)
            dup.dup = last
            parent = doc
            for part in path[:-2]:
                parent = parent[part]
            if len(path) == 1:
                return doc, last
            parent[path[-2]] = dup
    else:
        holder[last] = new
    return doc, None


def _write(doc: dict, path: Path, top_dup=None):
    lines = []
    for k, v in doc.items():
        lines.append(f"{json.dumps(str(k))} = {_toml_value(v)}")
        if k == top_dup:
            lines.append(lines[-1])
    path.write_text("\n".join(lines) + "\n")


def _cases():
    """(id, study file, where: "study" or "scene", path, mutant) — a deterministic selection.

    Every leaf of every shipped study gets a few mutants, chosen by cycling through the
    mutant list so that every kind meets every section somewhere; scene files are mutated
    through the first study that reads them.
    """
    cases, seen_scenes, turn = [], set(), 0
    for study in SHIPPED:
        doc = _base(study)
        targets = [("study", p) for p in _leaves(doc)]
        scene = doc.get("scene")
        if isinstance(scene, str):
            scene_path = (study.parent / scene).resolve()
            if scene_path not in seen_scenes:
                seen_scenes.add(scene_path)
                scene_doc = tomllib.loads(scene_path.read_text())
                targets += [("scene", p) for p in _leaves(scene_doc)]
        for where, path in targets:
            if where == "study" and path == ("scene",):
                continue
            value = doc if where == "study" else scene_doc
            for part in path:
                value = value[part]
            mutants = _mutants(value)
            for k in range(MUTANTS_PER_LEAF):
                mutant = mutants[(turn + k * 7) % len(mutants)]
                label = "missing" if mutant is MISSING else "duplicated" \
                    if mutant is DUPLICATED else _toml_value(mutant)[:12]
                cases.append(pytest.param(study, where, path, mutant,
                                          id=f"{study.stem}-{where}-{_key(path)}={label}"))
            turn += 1
    return cases


CASES = _cases()


def _materialize(study: Path, where: str, path, mutant, tmp: Path):
    """Write the mutated study (and scene) into ``tmp``; return (study file, mutated file)."""
    edit = [(path, mutant)]
    study_file, scene_file = write_variant(study, tmp, study_edits=edit if where == "study"
                                           else (), scene_edits=edit if where == "scene" else ())
    return study_file, (scene_file if where == "scene" else study_file)


def write_variant(study: Path, tmp: Path, study_edits=(), scene_edits=()):
    """The shrunk ``study`` with ``(path, value)`` edits, and its scene file with its own,
    written into ``tmp``; returns (study file, scene file or None)."""
    doc = _shrunk(_base(study))
    scene = doc.get("scene")
    scene_doc = None
    if isinstance(scene, str):
        scene_doc = tomllib.loads((study.parent / scene).resolve().read_text())
    top_dup = scene_top_dup = None
    for path, value in study_edits:
        doc, top_dup = _mutate(doc, path, value)
    for path, value in scene_edits:
        scene_doc, scene_top_dup = _mutate(scene_doc, path, value)
    doc.setdefault("output", {})["path"] = "out/result.nc"
    study_file = tmp / "study.toml"
    scene_file = None
    if scene_doc is not None:
        scene_file = tmp / "scene.toml"
        _write(scene_doc, scene_file, scene_top_dup)
        if isinstance(doc.get("scene"), str):
            doc["scene"] = "scene.toml"
    _write(doc, study_file, top_dup)
    return study_file, scene_file


def _section(key: str) -> str:
    return key.replace("[", ".").split(".")[0]


# Where an error may point when a value in a section changes: the section itself, or what
# depends on it (a scene decides the solver's parameters and outputs, which the inputs, fields,
# correlation and outputs name; inputs and fields decide what the method can treat).
DEPENDENTS = {
    "scene": {"scene", "inputs", "outputs", "fields", "correlation", "method"},
    "inputs": {"inputs", "correlation", "method"},
    "fields": {"fields", "method", "inputs"},
    "correlation": {"correlation", "method"},
    "outputs": {"outputs"},
}


def check_variant(study_file: Path, mutated_file: Path, where: str, path) -> str:
    """Validate one variant; returns "ok" or "refused", failing on anything else."""
    try:
        study = load_study(study_file)
    except StudyError as exc:
        text = str(exc)
        assert "\n" not in text and text.strip(), text
        mutated = "scene" if where == "scene" else _key(path)
        allowed = DEPENDENTS.get(_section(mutated), {_section(mutated)})
        if "not valid TOML" in text:
            assert exc.file == str(mutated_file), text
            return "refused"        # a syntax error has a line and column, no key
        assert exc.key, f"names no key: {text}"
        assert _section(exc.key) in allowed, f"mutated {mutated}, error names {exc.key}: {text}"
        # The file to edit: the one mutated, or the study where it depends on the scene file.
        assert exc.file == str(mutated_file) or \
            exc.file == str(study_file) and _section(exc.key) != "scene", text
        return "refused"
    design = study.method.plan(study.space, study.fields or None,
                               np.random.SeedSequence(study.spec.execution.seed))
    assert design.sizes["realization"] >= 1
    assert np.all(np.isfinite(design["inputs"].values))
    return "ok"


@pytest.mark.parametrize("study,where,path,mutant", CASES)
@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_malformed_variant_validates_and_plans_or_fails_in_one_line(study, where, path, mutant,
                                                                    tmp_path):
    study_file, mutated_file = _materialize(study, where, path, mutant, tmp_path)
    check_variant(study_file, mutated_file, where, path)
    assert not (tmp_path / "out").exists()


def test_fuzz_table_is_large_and_covers_every_kind_of_mutant():
    assert len(CASES) >= 300
    kinds = {type(c.values[3]).__name__ if c.values[3] not in (MISSING, DUPLICATED)
             else ("missing" if c.values[3] is MISSING else "dup") for c in CASES}
    assert {"bool", "str", "float", "int", "list", "dict", "missing", "dup"} <= kinds
    assert any(c.values[1] == "scene" for c in CASES)


# --------------------------------------------------------------------------- limits
STUDIES = REPO / "studies"
LIMITS_DOC = REPO / "docs" / "study-files.md"
KL = STUDIES / "gamut_bar" / "m1_cyclic_stochastic_uniform.toml"
BAR = STUDIES / "gamut_bar" / "m1_monotonic_deterministic_uniform.toml"
MPM = STUDIES / "smpm_jc_thin_plate_mc.toml"
# (docs row key, the bound as the row states it, study, study edits, scene-file edits, key the
# error names). Each variant asks one more than the bound (or the bound's product) allows.
LIMITS = [
    ("`method.samples` (monte-carlo)", "10⁷", STUDIES / "mc_exponential_decay.toml",
     [(("method", "samples"), 10**7 + 1)], [], "method.samples"),
    ("`method.samples` (monte-carlo), `method.realizations`", "10⁷", KL,
     [(("method", "realizations"), 10**7 + 1)], [], "method.realizations"),
    ("any other integer option", "10⁷", STUDIES / "mc_exponential_decay.toml",
     [(("method", "min_samples"), 10**7 + 1)], [], "method.min_samples"),
    ("`method.samples` (sobol)", "10⁷", STUDIES / "sobol_g.toml",
     [(("method", "samples"), 10**6 + 1)], [], "method.samples"),       # 8 inputs: × 10
    ("`method.resamples` (sobol)", "10⁸", STUDIES / "sobol_g.toml",
     [(("method", "samples"), 1024), (("method", "resamples"), 10**5)], [],
     "method.resamples"),
    ("`execution.workers`", "512", STUDIES / "ishigami_mc.toml",
     [(("execution", "workers"), 513)], [], "execution.workers"),
    ("`execution.batch`", "10⁷", STUDIES / "ishigami_mc.toml",
     [(("execution", "batch"), 10**7 + 1)], [], "execution.batch"),
    ("`execution.seed`", "2⁶⁴ − 1", STUDIES / "ishigami_mc.toml",
     [(("execution", "seed"), 2**64)], [], "execution.seed"),
    ("`fields[i].modes`", "1,000", KL,
     [(("fields", 0, "captured_variance"), MISSING), (("fields", 0, "modes"), 1001)], [],
     "fields[0].modes"),
    ("`fields[i].quadrature_points`", "2,000", KL,
     [(("fields", 0, "quadrature_points"), 2001)], [], "fields[0].quadrature_points"),
    ("`fields[i].germ.shape`", "0.012", KL,
     [(("fields", 0, "germ", "shape"), 0.0119)], [], "fields[0].germ.shape"),
    ("MPM `scene.cell_size`", "2 × 10⁷", MPM, [], [(("resolution",), 100.0)],
     "scene.resolution"),
    ("MPM `scene.particles_per_cell`", "8", MPM, [], [(("particles_per_cell",), 9)],
     "scene.particles_per_cell"),
    ("MPM `scene.threads`", "1,024", MPM, [], [(("threads",), 1025)], "scene.threads"),
    ("MPM `scene.padding`", "64", MPM, [], [(("padding",), 65)], "scene.padding"),
    ("MPM `scene.max_steps`", "10⁹", MPM, [], [(("max_steps",), 10**9 + 1)],
     "scene.max_steps"),
    ("MPM `scene.extent_margin`", "10⁶", MPM, [], [(("extent_margin",), 10**6 + 1)],
     "scene.extent_margin"),
    ("gamut bar `scene.local_bonds` | at most", "10⁶", BAR,
     [(("scene", "local_bonds"), 10**6 + 1)], [], "scene.local_bonds"),
    ("gamut bar `scene.cutoff`", "1,000", BAR, [(("scene", "cutoff"), 126.0)], [],
     "scene.cutoff"),                                       # 126 × 8 − 1 = 1007 families
    ("gamut bar `scene.local_bonds` | local_bonds", "10⁷", BAR,
     [(("scene", "local_bonds"), 500_000)], [], "scene.local_bonds"),  # × 24 = 1.2e7
    ("gamut bar `scene.curve_points`", "10⁶", BAR,
     [(("scene", "curve_points"), 10**6 + 1)], [], "scene.curve_points"),
    ("gamut bar `scene.cyclic_increment`", "10⁻⁴", KL,
     [(("scene", "cyclic_increment"), 0.5e-4)], [], "scene.cyclic_increment"),
    ("gamut bar `scene.cyclic_increment`", "10⁶", KL,
     [(("scene", "cycles"), 1000), (("scene", "cyclic_increment"), 1e-3)], [],
     "scene.cyclic_increment"),                             # 2000 loops × 4000 steps
    ("gamut bar `scene.cycles`", "1,000", KL, [(("scene", "cycles"), 1001)], [],
     "scene.cycles"),
    ("gamut bar `scene.cycles`, `scene.cycle_repeats`", "1,000", KL,
     [(("scene", "cycle_repeats"), 1001)], [], "scene.cycle_repeats"),
    ("gamut bar `scene.bisections`", "100", BAR, [(("scene", "bisections"), 101)], [],
     "scene.bisections"),
    ("gamut bar `scene.grid_seed`", "2⁶⁴ − 1", BAR, [(("scene", "grid_seed"), 2**64)], [],
     "scene.grid_seed"),
    ("analytic `scene.t.num`", "10⁶", STUDIES / "mc_exponential_decay.toml",
     [(("scene", "t", "num"), 10**6 + 1)], [], "scene.t.num"),
    ("analytic `scene.points`", "10⁷", STUDIES / "mc_random_E_bar.toml",
     [(("scene", "points"), 10**7 + 1)], [], "scene.points"),
    ("analytic `scene.delay`", "3,600 s", STUDIES / "mc_random_E_bar.toml",
     [(("scene", "delay"), 3601.0)], [], "scene.delay"),
]


def _limits_rows() -> list[str]:
    text = LIMITS_DOC.read_text()
    section = text[text.index("\n## Limits\n"):]
    section = section[:section.index("\n## ", 1)]
    return [line for line in section.splitlines() if line.startswith("| ")]


@pytest.mark.parametrize("row,bound,study,study_edits,scene_edits,key", LIMITS,
                         ids=[f"{lim[5]}-{i}" for i, lim in enumerate(LIMITS)])
def test_one_more_than_each_documented_limit_is_refused_in_one_line(
        row, bound, study, study_edits, scene_edits, key, tmp_path):
    assert any(line.startswith(f"| {row}") and bound in line for line in _limits_rows()), \
        f"docs/study-files.md, Limits: no row '{row}' stating {bound}"
    study_file, scene_file = write_variant(study, tmp_path, study_edits, scene_edits)
    with pytest.raises(StudyError) as caught:
        load_study(study_file)
    exc = caught.value
    assert exc.key == key, str(exc)
    assert exc.file == str(scene_file if scene_edits else study_file), str(exc)
    assert "\n" not in str(exc)


def test_every_documented_limit_is_exercised():
    tested = {row.split(" | ")[0] for row, *_ in LIMITS}
    for line in _limits_rows()[2:]:
        key = line.split(" | ")[0].removeprefix("| ")
        if key.startswith("A method") or key.startswith("any other"):
            continue
        assert any(key.startswith(t.removeprefix("| ")) or t.startswith(key) for t in tested), \
            f"documented limit without a test: {line}"


@pytest.mark.parametrize("study,edits", [
    (STUDIES / "mc_exponential_decay.toml", [(("method", "samples"), 10**7)]),
    (STUDIES / "ishigami_mc.toml", [(("execution", "seed"), 2**64 - 1),
                                   (("execution", "workers"), 512)]),
    (STUDIES / "sobol_g.toml", [(("method", "samples"), 10**6),
                                (("method", "resamples"), 100)]),
], ids=["samples-at-bound", "seed-and-workers-at-bound", "sobol-at-bound"])
def test_each_bound_itself_validates(study, edits, tmp_path):
    study_file, _ = write_variant(study, tmp_path, edits)
    load_study(study_file)


# --------------------------------------------------------------------------- the real CLI
CLI_VARIANTS = [
    (STUDIES / "ishigami_mc.toml", [(("inputs", 0, "lower"), -1e308),
                                   (("inputs", 0, "upper"), 1e308)], [], "inputs[0].lower"),
    (STUDIES / "ishigami_mc.toml", [(("method", "samples"), True)], [], "method.samples"),
    (STUDIES / "ishigami_mc.toml", [(("execution", "seed"), 2**64)], [], "execution.seed"),
    (MPM, [], [(("cell_size",), math.nan)], "scene.cell_size"),
    (BAR, [(("scene", "n_ro"), 1e300)], [], "scene.n_ro"),
]


@pytest.mark.parametrize("study,study_edits,scene_edits,key", CLI_VARIANTS,
                         ids=[v[3] for v in CLI_VARIANTS])
def test_cli_refuses_malformed_variant_with_exit_2_and_one_line(study, study_edits,
                                                                scene_edits, key, tmp_path):
    study_file, scene_file = write_variant(study, tmp_path, study_edits, scene_edits)
    env = {k: v for k, v in os.environ.items() if k != "UQFLOW_DEBUG"}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH")) if p)
    proc = subprocess.run([sys.executable, "-m", "uqflow.cli", "run", str(study_file)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    named = scene_file if scene_edits else study_file
    assert proc.returncode == 2, proc.stderr
    assert proc.stdout == ""
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.startswith(f"uqflow: error: {named}: {key}: "), proc.stderr
    assert not (tmp_path / "out").exists()
