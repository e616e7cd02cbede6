"""Pydantic validation errors as the one-line errors of uqflow: the first error of a study
file, a method's options or a solver's scene, naming the file and the user's key (without
pydantic's union members and wrappers) with a reason a user can act on.

Solvers validate their scenes with it; it lives apart from the study loader so that a solver
package (on a dask worker, or in a warm-up subprocess) imports pydantic and nothing of the
study layer.
"""

from __future__ import annotations

import difflib
from typing import Any, get_args

from pydantic import BaseModel, ValidationError

from uqflow.errors import StudyError
from uqflow.overrides import shown_value


def _key(loc) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


_MISSING = object()


def _user_loc(loc, data) -> tuple:
    """``loc`` without pydantic's own entries, walking the user's data alongside.

    pydantic puts the member of a union it tried (``'dict[str,any]'``, ``'str'``, ``'float'``,
    ``"literal['auto']"``, ``'function-after[...]'``) into ``loc``. A part is the user's key
    if it indexes the data at that point; a missing key is the user's key only as the last
    part; below a scalar nothing is.
    """
    out, here = [], data
    for i, part in enumerate(loc):
        last = i == len(loc) - 1
        if isinstance(here, dict) and isinstance(part, str):
            if part in here:
                out.append(part)
                here = here[part]
            elif last and here is not _MISSING:
                out.append(part)
        elif isinstance(here, list) and isinstance(part, int) and 0 <= part < len(here):
            out.append(part)
            here = here[part]
        elif here is _MISSING or isinstance(here, (dict, list)):
            # Data unknown (no raw data given): keep what does not look like a union member.
            if isinstance(part, int) or not any(c in part for c in "[]-") and \
                    part not in ("str", "int", "float", "bool", "list", "dict", "none"):
                out.append(part)
    return tuple(out)


def _reason(err: dict) -> str:
    kind = err["type"]
    if kind == "extra_forbidden":
        return "unknown key"
    if kind == "missing":
        return "required key is missing"
    if kind in ("model_type", "model_attributes_type", "dict_type"):
        return "must be a table"
    return err["msg"].removeprefix("Value error, ").removeprefix("Assertion failed, ")


def _value_at(data, loc):
    here = data
    for part in loc:
        try:
            here = here[part]
        except (KeyError, IndexError, TypeError):
            return _MISSING
    return here


def _model_at(model, loc) -> type[BaseModel] | None:
    """The pydantic model that holds the last key of ``loc``, starting from ``model``."""
    for part in loc:
        if isinstance(part, int):
            continue
        info = model.model_fields.get(part) if model is not None else None
        if info is None:
            return None
        model = _model_in(info.annotation)
    return model


def _model_in(annotation) -> type[BaseModel] | None:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in get_args(annotation):
        found = _model_in(arg)
        if found is not None:
            return found
    return None


def _unknown_key(name, model, extra_known=()) -> str:
    known = [*extra_known, *(model.model_fields if model is not None else ())]
    if not known:
        return "unknown key"
    close = difflib.get_close_matches(str(name), known, n=1)
    if close:
        return f"unknown key (did you mean '{close[0]}'?)"
    return f"unknown key (known: {', '.join(known)})"


def validation_error(exc: ValidationError, file: str, prefix: str = "",
                     data: Any = None, model: type[BaseModel] | None = None,
                     extra_known: tuple[str, ...] = ()) -> StudyError:
    """The first pydantic error as a one-line StudyError naming file and key.

    ``data`` (the validated input, optional) lets the key be the user's even where pydantic
    adds union members to the error location. Errors of the other members of the same union
    (same key) join the reason: "Input should be 'auto' or a valid boolean". ``model`` (the
    validated model class) lets an unknown key suggest the known ones; ``extra_known`` adds
    keys handled outside it (``kind`` beside a method's options).
    """
    errors = exc.errors()
    raw = _MISSING if data is None else data
    loc = _user_loc(errors[0]["loc"], raw)
    value = _value_at(raw, loc) if raw is not _MISSING else _MISSING
    reason = _reason(errors[0])
    if errors[0]["type"] == "extra_forbidden" and loc and model is not None:
        holder = _model_at(model, loc[:-1])
        reason = _unknown_key(loc[-1], holder, extra_known if len(loc) == 1 else ())
    for err in errors[1:]:
        if _user_loc(err["loc"], raw) != loc or err["type"] in ("missing", "extra_forbidden"):
            continue
        more = _reason(err)
        if more.startswith("Input should be ") and reason.startswith("Input should be "):
            more = more.removeprefix("Input should be ")
        if more not in reason:
            reason = f"{reason} or {more}"
    kind = errors[0]["type"]
    reason = reason.replace(" after validation", "")
    if value is not _MISSING and "got" not in reason and \
            kind not in ("missing", "extra_forbidden", "value_error", "assertion_error") and \
            (not isinstance(value, (dict, list)) or kind.endswith("_type")):
        reason = f"{reason}, got {shown_value(value)}"
    key = _key(loc)
    if key == "inputs" and errors[0]["type"] == "list_type":
        reason += " (write each input as an [[inputs]] table, with double brackets)"
    if prefix:
        key = f"{prefix}.{key}" if key else prefix
    return StudyError(reason, file=file, key=key or None)
