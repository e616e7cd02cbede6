"""Limit states: failure events of a study's outputs, declared in its ``[[limit_states]]``.

A limit state is "an output, reduced over its dims to one number per realization, beyond a
threshold": ``y > threshold`` (``exceeds``) or ``y < threshold`` (``below``). Its margin is
``g = threshold - y`` (exceeds) or ``g = y - threshold`` (below), in the output's unit:
``g > 0`` safe, ``g <= 0`` failure. A system combines limit states (or systems declared
before it): a series system fails when any member fails (``g = min`` of the members'), a
parallel one when all fail (``g = max``).

A solver error is not a failure event: a realization that did not run ok has NaN margins
everywhere, and is counted apart by the methods. The reference for users is
docs/reliability.md.

Reductions of an output with dims (one number per realization):

- ``"max"``, ``"min"``: over every dim;
- ``"final"``: the last value along the output's first numeric dim (time, step);
- ``{ at = { dim = label, ... } }``: the value at those coordinates, a string coordinate
  matched by its exact label, a numeric one by its value within a rounding tolerance;
- ``{ max_over = { dim = [labels] } }``: the max over those labels and over every other dim.

Dims that ``final`` or ``at`` leave are covered by their worst point: the largest value for
``exceeds``, the smallest for ``below`` (the event happens at any of them).

Discrete outcomes. A 0/1 output (its solver declares ``flag_values = [0, 1]``: the gamut
bar's ``broken``) takes ``is = true`` (failure when it is 1) or ``is = false``; that margin
is +1 (safe) or -1 (failure), read as ``exceeds = 0.5`` (``below = 0.5`` for false). An
event's time with a value meaning "not within the loading" (``not_within_loading``: the bar's
``break_cycle``, the composite's ``debonding_onset_strain``) takes ``below`` only below that
value and ``exceeds`` only up to it: beyond, the scene cannot answer. A limit state on a
discrete output (a flag, a count, a cycle, a value on the loading's grid) is ``discrete``:
its margin is a step function of the inputs, which FORM, SORM and subset simulation cannot
use (``LimitStates.require_continuous``).
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import xarray as xr

from uqflow.errors import StudyError
from uqflow.layout import (DISCRETE_VALUES, FLAG_VALUES, LIMIT_STATE, NOT_WITHIN_LOADING,
                           OUTPUT_VALUES, REALIZATION, UNDEFINED_WHEN, UNITS, ok_mask,
                           output_names)

EXCEEDS, BELOW = ">", "<"
SERIES, PARALLEL = "series", "parallel"
#: the reductions written as a word; "value" is a scalar output's own value
WORD_REDUCTIONS = ("max", "min", "final")
#: the reductions written as a table, with labels of some dims
TABLE_REDUCTIONS = ("at", "max_over")
_STATE_KEYS = ("name", "output", "reduce", "exceeds", "below", "is")
#: ``is = true`` reads as ``exceeds = OUTCOME_THRESHOLD`` (``is = false`` as ``below``): between
#: the two values of a 0/1 outcome, so a value exactly 0 or 1 is never at the threshold
OUTCOME_THRESHOLD = 0.5
_SYSTEM_KEYS = ("name", SERIES, PARALLEL)
# A coordinate computed as start + i*step (or interval*i, linspace) differs from the decimal
# a user writes by a few ulp (2.2e-16) of the grid's largest value, and by at most ~1e-10 of
# it when summed over 10^6 steps: 1e-9 of that value bounds the rounding and stays far below
# the spacing of any grid a solver records.
_COORD_RTOL = 1e-9


@dataclass(frozen=True)
class Reduction:
    """How an output's values over its dims become one number per realization.

    ``kind``: "value" (a scalar output), "max", "min", "final", "at" or "max_over";
    ``labels``: for "at" and "max_over", ((dim, (label, ...)), ...) with each label as the
    output's coordinate holds it; ``along``: for "final", the dim whose last value is taken.
    """

    kind: str
    labels: tuple[tuple[str, tuple], ...] = ()
    along: str | None = None

    def apply(self, values: xr.DataArray, comparison: str) -> xr.DataArray:
        """``values`` (realization, *dims) reduced to (realization,); a NaN anywhere in what
        is reduced gives NaN (a NaN point is no value)."""
        others = [d for d in values.dims if d != REALIZATION]
        if self.kind == "value" or not others:
            return values
        if self.kind in ("max", "min"):
            return getattr(values, self.kind)(others, skipna=False)
        if self.kind == "final":
            values = values.isel({self.along: -1})
        elif self.kind == "at":
            values = _select(values, {dim: labels[0] for dim, labels in self.labels})
        else:                                   # max_over
            values = _select(values, {dim: list(labels) for dim, labels in self.labels})
            return values.max([d for d in values.dims if d != REALIZATION], skipna=False)
        rest = [d for d in values.dims if d != REALIZATION]
        if not rest:
            return values
        worst = "max" if comparison == EXCEEDS else "min"
        return getattr(values, worst)(rest, skipna=False)

    def describe(self, output: str) -> str:
        """``output`` reduced, in words: "max of y", "y at the last t", "y at t = 0.0001,
        probe = H", "max of y over probe in [H, I]"."""
        if self.kind == "value":
            return output
        if self.kind == "final":
            return f"{output} at the last {self.along}"
        if self.kind == "at":
            return f"{output} at " + ", ".join(f"{d} = {_label_text(ls[0])}"
                                               for d, ls in self.labels)
        if self.kind == "max_over":
            return f"max of {output} over " + ", ".join(
                f"{d} in [{', '.join(map(_label_text, ls))}]" for d, ls in self.labels)
        return f"{self.kind} of {output}"


@dataclass(frozen=True)
class LimitState:
    """One event "output, reduced over its dims, beyond a threshold"."""

    name: str
    output: str
    reduce: Reduction
    comparison: str            # EXCEEDS ">" or BELOW "<"
    threshold: float           # in the output's SI unit
    units: str = ""            # the output's unit, for reports
    #: ``is = true``/``false`` on a 0/1 outcome: the margin is +1 (safe) or -1 (failure)
    outcome: bool = False
    #: the output takes discrete values (a flag, a count, a cycle; ``output_values``)
    discrete_output: bool = False

    @property
    def discrete(self) -> bool:
        """Whether the margin is a step function of the inputs (an outcome or a discrete
        output): no gradient or design point to find, only events to count."""
        return self.outcome or self.discrete_output

    def margin(self, values: xr.DataArray) -> np.ndarray:
        """g (realization,) of the output's ``values`` (realization, *dims)."""
        y = np.asarray(self.reduce.apply(values, self.comparison).values, dtype=float)
        g = self.threshold - y if self.comparison == EXCEEDS else y - self.threshold
        if self.outcome:
            # +1 safe, -1 failure; a value that is neither 0 nor 1 is no outcome: no margin
            g = np.where((y == 0) | (y == 1), np.sign(g), np.nan)
        return g

    def describe(self) -> str:
        """"max of y > 2 m", "broken is true": the event in words."""
        if self.outcome:
            return f"{self.reduce.describe(self.output)} is " \
                   f"{'true' if self.comparison == EXCEEDS else 'false'}"
        unit = f" {self.units}" if self.units not in ("", "1") else ""   # "1": no unit
        return f"{self.reduce.describe(self.output)} {self.comparison} {self.threshold:g}{unit}"


@dataclass(frozen=True)
class LimitStateSystem:
    """Several limit states combined: series (any member fails) or parallel (all fail)."""

    name: str
    kind: str                  # SERIES or PARALLEL
    members: tuple[str, ...]

    def describe(self) -> str:
        """"a or b fails" (series), "a and b fail" (parallel)."""
        if self.kind == SERIES:
            return f"{' or '.join(self.members)} fails"
        return f"{' and '.join(self.members)} fail"


class LimitStates:
    """The study's limit states and systems; ``names``: the states, then the systems, each
    in study order (the labels of the ``limit_state`` dim)."""

    def __init__(self, states: list[LimitState], systems: list[LimitStateSystem]):
        self.states = list(states)
        self.systems = list(systems)
        self.names = [s.name for s in self.states] + [s.name for s in self.systems]

    def __len__(self) -> int:
        return len(self.names)

    def __getitem__(self, name: str) -> LimitState | LimitStateSystem:
        for item in (*self.states, *self.systems):
            if item.name == name:
                return item
        raise KeyError(name)

    def __repr__(self) -> str:
        return f"LimitStates({', '.join(self.names)})"

    def is_discrete(self, name: str) -> bool:
        """Whether limit state or system ``name`` has a discrete margin (a system: when any
        member has)."""
        item = self[name]
        if isinstance(item, LimitStateSystem):
            return any(self.is_discrete(m) for m in item.members)
        return item.discrete

    def choose(self, chosen: str | None, method: str, systems: bool) -> str:
        """The one limit state (or, with ``systems``, system) a method analyses: ``chosen``
        (its ``limit_state`` option) or the study's only one; one line naming
        ``method.limit_state`` otherwise."""
        names = list(self.names)
        if chosen is None:
            if len(names) != 1:
                raise StudyError(f"the study has {len(names)} limit states "
                                 f"({', '.join(names)}) and {method} analyses one"
                                 f"{' (a system too)' if systems else ''}: name it with "
                                 f"limit_state = \"...\"", key="method.limit_state")
            return names[0]
        if chosen not in names:
            raise StudyError(f"'{chosen}' is not among the study's limit states "
                             f"({', '.join(names)})", key="method.limit_state")
        return chosen

    def require_continuous(self, name: str, method: str) -> None:
        """Refuse, in one line naming ``method.limit_state``, a discrete limit state for a
        method that follows the margin's gradient (FORM, SORM) or its level sets (subset
        simulation): a step function has no design point and no intermediate levels."""
        if self.is_discrete(name):
            raise StudyError(f"limit state '{name}' has a discrete margin (a 0/1 outcome or "
                             f"an output with discrete values): {method} needs a continuous "
                             f"one; use monte-carlo, or a limit state on a continuous output",
                             key="method.limit_state")

    def margins(self, runs: xr.Dataset) -> xr.DataArray:
        """g (realization, limit_state): > 0 safe, <= 0 failure, in each output's unit
        (a system's margin in its members' units, meaningful by its sign where they differ);
        NaN where the realization did not run ok (a solver error is not a failure)."""
        ok = ok_mask(runs)
        columns: dict[str, np.ndarray] = {}
        for state in self.states:
            if state.output not in runs.data_vars:
                raise KeyError(f"limit state '{state.name}': the runs have no output "
                               f"'{state.output}'")
            with np.errstate(invalid="ignore"):
                g = state.margin(runs[state.output])
            columns[state.name] = np.where(ok, g, np.nan)
        for system in self.systems:
            members = np.stack([columns[m] for m in system.members])
            # np.min/np.max propagate NaN: a member without a margin leaves the system without
            columns[system.name] = members.min(axis=0) if system.kind == SERIES else \
                members.max(axis=0)
        n = runs.sizes[REALIZATION]
        data = np.stack([columns[name] for name in self.names], axis=1) if self.names else \
            np.zeros((n, 0))
        coords = {LIMIT_STATE: list(self.names)}
        if REALIZATION in runs.coords:
            coords[REALIZATION] = runs[REALIZATION].values
        return xr.DataArray(data, dims=(REALIZATION, LIMIT_STATE), coords=coords)

    def failures(self, runs: xr.Dataset) -> xr.DataArray:
        """bool (realization, limit_state): g <= 0; False where g is NaN (a realization that
        did not run ok is no failure event: count failures among ``ok_mask(runs)``)."""
        g = self.margins(runs)
        with np.errstate(invalid="ignore"):
            return g <= 0

    @classmethod
    def from_tables(cls, tables: Any, template: xr.Dataset, where: str = "") -> "LimitStates":
        """The study's ``[[limit_states]]`` tables, validated against ``template`` (the
        solver's ``outputs()`` restricted to the study's outputs, or runs: a ``realization``
        dim is ignored). Every mistake is a one-line ``StudyError`` naming ``where`` (the
        file) and the key, ``limit_states[i].<key>``."""
        if not isinstance(tables, list):
            raise StudyError("must be a list of tables: write each limit state as a "
                             "[[limit_states]] table, with double brackets", file=where or None,
                             key="limit_states")
        if not tables:
            raise StudyError("must hold at least one [[limit_states]] table",
                             file=where or None, key="limit_states")
        states, systems, seen = [], [], {}
        for i, table in enumerate(tables):
            at = f"limit_states[{i}]"
            try:
                if not isinstance(table, dict):
                    raise StudyError(f"must be a table, got {_shown(table)}", key=at)
                name = _name(table, at)
                if name in seen:
                    raise StudyError(f"limit state '{name}' is declared twice (also "
                                     f"limit_states[{seen[name]}])", key=f"{at}.name")
                if SERIES in table or PARALLEL in table:
                    systems.append(_system(table, at, name, seen))
                else:
                    states.append(_state(table, at, name, template))
                seen[name] = i
            except StudyError as exc:
                raise StudyError(exc.reason, file=where or None, key=exc.key) from None
        try:
            _lost_outcomes(states, template)
        except StudyError as exc:
            raise StudyError(exc.reason, file=where or None, key=exc.key) from None
        return cls(states, systems)


def _select(values: xr.DataArray, labels: dict) -> xr.DataArray:
    """``values`` at ``labels`` ({dim: label or [labels]}); a dim without coordinate is
    labelled by position."""
    by_label = {d: v for d, v in labels.items() if d in values.coords}
    by_position = {d: v for d, v in labels.items() if d not in values.coords}
    return values.sel(by_label).isel(by_position)


# ----------------------------------------------------------------------------- validation

def _shown(value) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return f"'{value}'"
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return "a list"
    return repr(value)


def _label_text(label) -> str:
    return f"{label:g}" if isinstance(label, float) else str(label)


def _unknown_keys(table: dict, known: tuple[str, ...], at: str) -> None:
    for key in table:
        if key not in known:
            # a misspelt key of the other kind of table (serie = [...]) is suggested too
            close = difflib.get_close_matches(str(key), (*_STATE_KEYS, *_SYSTEM_KEYS), n=1)
            hint = f"did you mean '{close[0]}'?" if close else f"known: {', '.join(known)}"
            raise StudyError(f"unknown key ({hint})", key=f"{at}.{key}")


def _text(value, key: str, what: str) -> str:
    if not isinstance(value, str):
        raise StudyError(f"must be {what} (a string), got {_shown(value)}", key=key)
    if not value.strip():
        raise StudyError("must not be empty or blank", key=key)
    if any(ord(c) < 32 or ord(c) == 127 for c in value):
        raise StudyError(f"must not contain control characters, got {value!r}", key=key)
    return value


def _name(table: dict, at: str) -> str:
    if "name" not in table:
        raise StudyError("required key is missing", key=f"{at}.name")
    return _text(table["name"], f"{at}.name", "a name")


def _system(table: dict, at: str, name: str, seen: dict[str, int]) -> LimitStateSystem:
    _unknown_keys(table, _SYSTEM_KEYS, at)
    if SERIES in table and PARALLEL in table:
        raise StudyError("a system is either series or parallel, not both: keep one",
                         key=f"{at}.{PARALLEL}")
    kind = SERIES if SERIES in table else PARALLEL
    members = table[kind]
    if not isinstance(members, list) or len(members) < 2:
        raise StudyError(f"must list at least two limit states by name, got "
                         f"{_shown(members)}", key=f"{at}.{kind}")
    for j, member in enumerate(members):
        key = f"{at}.{kind}[{j}]"
        _text(member, key, "the name of a limit state")
        if member == name:
            raise StudyError(f"a system cannot be its own member ('{name}')", key=key)
        if member in members[:j]:
            raise StudyError(f"'{member}' is listed twice", key=key)
        if member not in seen:
            raise StudyError(f"no limit state '{member}' is declared before this system "
                             f"(declared: {', '.join(seen) or 'none'})", key=key)
    return LimitStateSystem(name=name, kind=kind, members=tuple(members))


def _state(table: dict, at: str, name: str, template: xr.Dataset) -> LimitState:
    _unknown_keys(table, _STATE_KEYS, at)
    if "output" not in table:
        raise StudyError("required key is missing (or write a system with series = [...] or "
                         "parallel = [...])", key=f"{at}.output")
    output = _text(table["output"], f"{at}.output", "an output's name")
    # runs as the template: their outputs, not the framework's columns (status, inputs, ...)
    outputs = output_names(template) if REALIZATION in template.dims else \
        [str(v) for v in template.data_vars]
    if output not in outputs:
        raise StudyError(f"the study has no output '{output}' (it has "
                         f"{', '.join(outputs) or 'none'})", key=f"{at}.output")
    given = [word for word in ("exceeds", "below", "is") if word in table]
    if len(given) != 1:
        extra = f", not both ({' and '.join(given)})" if len(given) == 2 else \
            ", not all three" if given else ""
        raise StudyError("give exactly one of exceeds = <threshold> (failure when the value "
                         "is above it), below = <threshold>, or is = true/false (a 0/1 "
                         "outcome)" + extra,
                         key=f"{at}.{given[-1]}" if given else f"{at}.exceeds")
    word = given[0]
    values = template[output]
    if word == "is":
        comparison, threshold = _outcome(table["is"], values, f"{at}.is")
    else:
        threshold = table[word]
        if isinstance(threshold, bool) or not isinstance(threshold, (int, float)):
            raise StudyError(f"must be a number (in the output's unit), got "
                             f"{_shown(threshold)}", key=f"{at}.{word}")
        if not math.isfinite(threshold):
            raise StudyError(f"must be a finite number, got {threshold!r}",
                             key=f"{at}.{word}")
        comparison = EXCEEDS if word == "exceeds" else BELOW
        _within_loading(values, comparison, float(threshold), f"{at}.{word}")
    reduce = _reduction(table.get("reduce"), "reduce" in table, values, f"{at}.reduce")
    discrete = str(values.attrs.get(OUTPUT_VALUES, "")) == DISCRETE_VALUES or \
        _is_flag(values)
    return LimitState(name=name, output=output, reduce=reduce, comparison=comparison,
                      threshold=float(threshold), units=str(values.attrs.get(UNITS, "")),
                      outcome=word == "is", discrete_output=discrete)


def _is_flag(values: xr.DataArray) -> bool:
    """Whether the solver declares ``values`` a 0/1 outcome (``flag_values = [0, 1]``)."""
    flags = np.atleast_1d(np.asarray(values.attrs.get(FLAG_VALUES, []), dtype=float))
    return flags.size == 2 and set(flags.tolist()) == {0.0, 1.0}


def _outcome(value, values: xr.DataArray, key: str) -> tuple[str, float]:
    """The comparison and threshold of ``is = value`` on a 0/1 outcome."""
    if not isinstance(value, bool):
        raise StudyError(f"must be true or false (a 0/1 outcome is or is not), got "
                         f"{_shown(value)}", key=key)
    if not _is_flag(values):
        raise StudyError(f"output '{values.name}' is not a 0/1 outcome (its solver declares no "
                         f"{FLAG_VALUES} = [0, 1]): compare it with exceeds = <threshold> or "
                         f"below = <threshold>", key=key)
    return (EXCEEDS if value else BELOW), OUTCOME_THRESHOLD


def _within_loading(values: xr.DataArray, comparison: str, threshold: float,
                    key: str) -> None:
    """Refuse a threshold on an event's time beyond its "not within the loading" value:
    realizations without the event have that value, and would be miscounted."""
    if NOT_WITHIN_LOADING not in values.attrs:
        return
    # A value at the threshold fails: below = t fails y <= t, exceeds = t fails y >= t; a
    # realization without the event has y = beyond, and its event lies somewhere past it.
    beyond = float(np.asarray(values.attrs[NOT_WITHIN_LOADING]).reshape(-1)[0])
    if comparison == BELOW and threshold >= beyond:
        raise StudyError(f"output '{values.name}' is {beyond:g} where the event did not "
                         f"happen within the loading, so below = {threshold:g} would count "
                         f"those realizations as failures: the scene answers thresholds below "
                         f"{beyond:g}", key=key)
    if comparison == EXCEEDS and threshold > beyond:
        raise StudyError(f"output '{values.name}' is {beyond:g} where the event did not "
                         f"happen within the loading, so exceeds = {threshold:g} would count "
                         f"those realizations as safe: the scene answers thresholds up to "
                         f"{beyond:g}", key=key)


def _lost_outcomes(states: list[LimitState], template: xr.Dataset) -> None:
    """Refuse limit states that would lose the realizations of an outcome: outputs the study
    stores without value when the outcome happens (a broken bar's later loops) make those
    realizations failed, and a limit state on an output they do have would leave them out."""
    missing_when: dict[str, list[str]] = {}
    for name in template.data_vars:
        flag = template[name].attrs.get(UNDEFINED_WHEN)
        if flag:
            missing_when.setdefault(str(flag), []).append(str(name))
    for state in states:
        own = template[state.output].attrs.get(UNDEFINED_WHEN)
        for flag, outputs in missing_when.items():
            if own == flag:
                continue               # the limit state's own output has no value there
            raise StudyError(f"the study stores {', '.join(map(repr, outputs))}, which have no "
                             f"value where '{flag}' is 1: those realizations would be failed, "
                             f"and limit state '{state.name}' would leave them out instead of "
                             f"judging them; list only the outputs the study needs in "
                             f"outputs = [...]", key="outputs")


def _dims(values: xr.DataArray) -> list[str]:
    return [str(d) for d in values.dims if d != REALIZATION]


def _is_numeric(values: xr.DataArray, dim: str) -> bool:
    if dim not in values.coords:
        return True                     # a dim without coordinate: labels are positions
    return np.issubdtype(values[dim].dtype, np.number)


def _coordinate(values: xr.DataArray, dim: str) -> np.ndarray:
    if dim not in values.coords:
        return np.arange(values.sizes[dim])
    return np.asarray(values[dim].values)


def _reduction(spec, given: bool, values: xr.DataArray, key: str) -> Reduction:
    dims = _dims(values)
    if not given:
        if dims:
            raise StudyError(f"output '{values.name}' has dims ({', '.join(dims)}): say how "
                             f"to reduce them to one number, reduce = \"max\", \"min\", "
                             f"\"final\", {{ at = {{ ... }} }} or {{ max_over = {{ ... }} }}",
                             key=key)
        return Reduction("value")
    if isinstance(spec, str):
        if spec not in WORD_REDUCTIONS:
            raise StudyError(f"unknown reduction '{spec}' (known: "
                             f"{', '.join(WORD_REDUCTIONS)}, or a table at = {{ ... }} or "
                             f"max_over = {{ ... }})", key=key)
        if spec != "final":
            return Reduction(spec)
        numeric = [d for d in dims if _is_numeric(values, d)]
        if not numeric:
            raise StudyError(f"output '{values.name}' has no numeric dim to take the last "
                             f"value along (dims: {', '.join(dims) or 'none'})", key=key)
        return Reduction("final", along=numeric[0])
    if not isinstance(spec, dict) or len(spec) != 1:
        raise StudyError(f"must be one of {', '.join(map(repr, WORD_REDUCTIONS))} or a table "
                         f"with one key, at = {{ dim = label }} or max_over = "
                         f"{{ dim = [labels] }}, got {_shown(spec)}", key=key)
    kind, points = next(iter(spec.items()))
    if kind not in TABLE_REDUCTIONS:
        close = difflib.get_close_matches(str(kind), TABLE_REDUCTIONS, n=1)
        hint = f"did you mean '{close[0]}'?" if close else \
            f"known: {', '.join(TABLE_REDUCTIONS)}"
        raise StudyError(f"unknown reduction ({hint})", key=f"{key}.{kind}")
    key = f"{key}.{kind}"
    if not isinstance(points, dict) or not points:
        what = "dim = label" if kind == "at" else "dim = [labels]"
        raise StudyError(f"must be a table {{ {what}, ... }} naming at least one of the "
                         f"output's dims ({', '.join(dims) or 'none'}), got {_shown(points)}",
                         key=key)
    labels = []
    for dim, given_labels in points.items():
        dim_key = f"{key}.{dim}"
        if dim not in dims:
            raise StudyError(f"output '{values.name}' has no dim '{dim}' (its dims: "
                             f"{', '.join(dims) or 'none'})", key=dim_key)
        if kind == "at":
            labels.append((dim, (_label(values, dim, given_labels, dim_key),)))
            continue
        if not isinstance(given_labels, list) or not given_labels:
            raise StudyError(f"must be a non-empty list of labels of dim '{dim}', got "
                             f"{_shown(given_labels)}", key=dim_key)
        found = []
        for j, label in enumerate(given_labels):
            matched = _label(values, dim, label, f"{dim_key}[{j}]")
            if matched in found:
                raise StudyError(f"{_shown(label)} is listed twice", key=f"{dim_key}[{j}]")
            found.append(matched)
        labels.append((dim, tuple(found)))
    return Reduction(kind, labels=tuple(labels))


def _label(values: xr.DataArray, dim: str, label, key: str):
    """The coordinate of ``dim`` that ``label`` names, as the output holds it."""
    coordinate = _coordinate(values, dim)
    if _is_numeric(values, dim):
        if isinstance(label, bool) or not isinstance(label, (int, float)) or \
                not math.isfinite(label):
            raise StudyError(f"dim '{dim}' has numeric coordinates: give a finite number, got "
                             f"{_shown(label)}", key=key)
        scale = float(np.max(np.abs(coordinate))) if coordinate.size else 0.0
        distance = np.abs(coordinate.astype(float) - float(label))
        nearest = int(np.argmin(distance)) if coordinate.size else None
        if nearest is None or distance[nearest] > _COORD_RTOL * scale:
            near = "" if nearest is None else \
                f"; the nearest is {_label_text(coordinate[nearest].item())}"
            raise StudyError(f"output '{values.name}' has no {dim} = {_label_text(label)} "
                             f"(its {dim} runs from {_label_text(coordinate.min().item())} to "
                             f"{_label_text(coordinate.max().item())}{near})", key=key)
        return coordinate[nearest].item()
    if not isinstance(label, str):
        raise StudyError(f"dim '{dim}' has labels: give one as a string, got {_shown(label)}",
                         key=key)
    known = [str(c) for c in coordinate]
    if label not in known:
        shown = ", ".join(known) if len(known) <= 12 else ", ".join(known[:12]) + ", ..."
        raise StudyError(f"output '{values.name}' has no {dim} '{label}' (its {dim} labels: "
                         f"{shown})", key=key)
    return coordinate[known.index(label)].item()
