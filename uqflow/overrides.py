"""How ``--set KEY=VALUE`` overrides are read, recorded and applied (docs/study-files.md):
the command line's form, the ``key = value`` lines a result records (``study_overrides``) and
setting a dotted key in a TOML table. Kept apart from ``uqflow.study`` so that a report
rebuilding the scene a result ran applies the overrides as the run did without importing the
study machinery."""

from __future__ import annotations

import copy
import json
import re
import tomllib
from collections.abc import Mapping
from typing import Any

from uqflow.errors import StudyError


#: where an override comes from, as errors name it
SET_OPTION = "--set"


def parse_override(text: str) -> tuple[str, Any]:
    """``KEY=VALUE`` of ``--set`` as (key, value): the value is read as a TOML value (``64``,
    ``0.1``, ``"lhs"``, ``true``, ``[1, 2]``, ``{ model = "ishigami" }``); a bare word that is
    not valid TOML (``pce``, ``sobol``) is taken as a string."""
    key, equals, value = text.partition("=")
    key = key.strip()
    if not equals or not key:
        raise StudyError(f"expected KEY=VALUE (e.g. method.samples=64), got {text!r}",
                         key=SET_OPTION)
    try:
        parsed = tomllib.loads(f"value = {value.strip()}")
    except tomllib.TOMLDecodeError:
        return key, value.strip()
    return key, parsed["value"] if list(parsed) == ["value"] else value.strip()


def toml_value(value) -> str:
    """``value`` written as a TOML value (what ``parse_override`` reads back)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        text = repr(float(value)) if isinstance(value, float) else str(value)
        return {"nan": "nan", "inf": "inf", "-inf": "-inf"}.get(text, text)
    if isinstance(value, str):
        # JSON's escapes (\", \\, \n, \uXXXX) are TOML's; non-ASCII stays as it is, but
        # DEL, which JSON leaves and TOML refuses
        return json.dumps(value, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{ " + ", ".join(f"{json.dumps(str(k), ensure_ascii=False)} = {toml_value(v)}"
                                for k, v in value.items()) + " }"
    return toml_value(str(value))  # a date or time read from TOML


def read_overrides(text: str) -> dict[str, Any]:
    """The overrides a result records (its ``study_overrides`` attribute, ``key = value``
    lines: ``Study.overrides_text``) as {key: value}, in their order."""
    return dict(parse_override(line.replace(" = ", "=", 1)) for line in text.splitlines()
                if line.strip())


def key_parts(key: str) -> list[str]:
    """``inputs.0.cv`` or ``inputs[0].cv`` as ["inputs", "0", "cv"]."""
    return [part for part in re.sub(r"\[(\d+)\]", r".\1", key).split(".")]


def set_key(document: dict, key: str, value) -> None:
    """Set the dotted ``key`` of the TOML ``document`` in place (an array of tables entered
    by index, ``inputs.0.cv``), creating tables on the way; a one-line ``StudyError`` naming
    ``--set`` where the key cannot be set. How an override applies, also to a scene table a
    report rebuilds from a result (``read_overrides``)."""
    parts = key_parts(key)
    if any(not part.strip() for part in parts):
        raise StudyError(f"'{key}' is not a dotted key (e.g. method.samples, inputs.0.cv)",
                         key=SET_OPTION)
    here, path = document, []
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        where = ".".join(path) or "the study"
        if isinstance(here, list):
            if not part.isdigit() or int(part) >= len(here):
                raise StudyError(f"{key}: {where} has {len(here)} entries (0 to "
                                 f"{len(here) - 1}); {SET_OPTION} sets keys of an entry by "
                                 f"its index, it adds none", key=SET_OPTION)
            part = int(part)
        elif not isinstance(here, dict):
            raise StudyError(f"{key}: {where} is {shown_value(here)}, not a table",
                             key=SET_OPTION)
        if last:
            here[part] = copy.deepcopy(value)
        else:
            if isinstance(here, dict) and part not in here:
                here[part] = {}
            here = here[part]
        path.append(str(part))


def shown_value(value) -> str:
    """A value as an error message shows it (short; tables and arrays by their kind)."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return "an array"
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."
