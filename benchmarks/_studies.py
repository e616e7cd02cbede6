"""Study files the MPM benchmarks write into their scratch folders: independent normal inputs
of one scene, a method table and an execution table, as a user would write them."""

from __future__ import annotations

import re
from pathlib import Path


def toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    return repr(value)


def write_normal_study(path: Path, *, name: str, scene: str, outputs, means: dict,
                       cv: float | dict, method: dict, execution: dict,
                       result: str) -> Path:
    """Write the study to ``path``: input ``k`` normal with mean ``means[k]`` and C.V. ``cv``
    (or ``cv[k]``), then ``[method]``, ``[execution]`` and ``[output] path = result``."""
    lines = [f"name = {toml_value(name)}", 'solver = "mpm"', f"scene = {toml_value(scene)}",
             f"outputs = {toml_value(list(outputs))}", ""]
    for input_name, mean in means.items():
        c = cv.get(input_name) if isinstance(cv, dict) else cv
        lines += ["[[inputs]]", f"name = {toml_value(input_name)}", 'distribution = "normal"',
                  f"mean = {mean!r}", f"cv = {c!r}", ""]
    for table, entries in (("method", method), ("execution", execution)):
        lines += [f"[{table}]", *(f"{k} = {toml_value(v)}" for k, v in entries.items()), ""]
    lines += ["[output]", f"path = {toml_value(result)}", ""]
    path.write_text("\n".join(lines))
    return path


def write_scene_variant(source: str, path: Path, **keys) -> Path:
    """A shipped scene (``studies/scenes/<source>``) with top-level ``keys`` set to new values
    (``outputs`` and other arrays may span lines); each key must stand there exactly once."""
    from _record import ROOT

    text = (ROOT / "studies" / "scenes" / source).read_text()
    for key, value in keys.items():
        pattern = rf"(?ms)^{key} = \[.*?\]" if isinstance(value, (list, tuple)) else \
            rf"(?m)^{key} = .*$"
        text, found = re.subn(pattern, f"{key} = {toml_value(value)}", text)
        if found != 1:
            raise SystemExit(f"scene {source}: expected one '{key}' entry, found {found}")
    path.write_text(text)
    return path
