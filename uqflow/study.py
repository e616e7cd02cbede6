"""Study files: TOML validated with pydantic, resolved into the objects a run needs.

``load_study(path)`` reads and checks everything a run needs before anything runs: the schema,
the solver and its scene, the inputs against the solver's parameters, the correlation, the
outputs, the method options and the method's own demands on the inputs (``check``).
Every problem is a one-line ``StudyError`` ``<file>: <key>: <reason>`` naming the key as the
user wrote it (``inputs[0].cv``, ``method.samples``, ``scene.model``). Relative paths resolve
against the study file's folder. The reference for users is docs/study-files.md.
"""

from __future__ import annotations

import copy
import hashlib
import re
import tomllib
import unicodedata
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import (AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field,
                      ValidationError, field_validator)

from uqflow.errors import SceneError, StudyError
from uqflow.inputs import DISTRIBUTIONS, InputSpace, RandomInput
from uqflow.levels import Levels, LevelsSpec, level_solver, resolve_levels, scene_with
from uqflow.limit_states import LimitStates
from uqflow.methods import PropagationMethod, get_method
from uqflow.methods.base import MAX_REALIZATIONS
# the --set mechanics live in uqflow.overrides; their names stay importable from here
from uqflow.overrides import (SET_OPTION, key_parts, parse_override,  # noqa: F401
                              read_overrides, set_key, shown_value, toml_value)
from uqflow.solver import Solver, get_solver
from uqflow.validation import validation_error  # noqa: F401 - solvers imported it from here


class _Strict(BaseModel):
    # Strict: an integer key takes a TOML integer only (not 2.0 or "2"), a number an integer
    # or a float, and nothing takes NaN or infinity.
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)


def _not_bool(value):
    # pydantic's lax mode reads true/false as 1/0; in a TOML file a boolean is never a number.
    if isinstance(value, bool):
        raise ValueError(f"must be a number, got {str(value).lower()}")
    return value


def _integer(value):
    # Strict mode already refuses 2.0 for an integer; say how to write it.
    if isinstance(value, float) and value.is_integer():
        raise ValueError(f"must be an integer: write {value:.0f}, not {value!r}")
    return _not_bool(value)


def _visible(value: str) -> str:
    # A name reaches file names, netCDF names and one-line messages: no blank names and no
    # control characters (a NUL byte cannot even be part of a path).
    if not value.strip():
        raise ValueError("must not be empty or blank")
    if any(unicodedata.category(c) == "Cc" for c in value):
        raise ValueError(f"must not contain control characters, got {value!r}")
    return value


Text = Annotated[str, AfterValidator(_visible)]
Float = Annotated[float, BeforeValidator(_not_bool)]
Number = Annotated[float | None, BeforeValidator(_not_bool)]
Int = Annotated[int, BeforeValidator(_integer)]

# Local dask workers are processes of ~270 MiB each (the interpreter with numpy, xarray,
# dask and numba loaded, BENCHMARKS.md): 512 of them fill the largest single nodes.
MAX_WORKERS = 512
# The seed is stored as a netCDF attribute, whose widest integer type is unsigned 64-bit.
MAX_SEED = 2**64 - 1
_HOST = r"(?:[A-Za-z0-9_](?:[A-Za-z0-9_.-]*[A-Za-z0-9_])?|\[[0-9A-Fa-f:.]+\])"
_PORT = r"(?:6553[0-5]|655[0-2]\d|65[0-4]\d{2}|6[0-4]\d{3}|[1-5]\d{4}|[1-9]\d{0,3})"
_SCHEDULER_FORMS = (
    re.compile(rf"(?:tcp|tls|ucx|ws|wss)://{_HOST}:{_PORT}"),
    re.compile(r"inproc://\S+"),
    re.compile(rf"{_HOST}:{_PORT}"),
)


def scheduler_address_problem(address: str) -> str | None:
    """Why ``address`` is not a dask scheduler address, or None if its form is one.

    Forms: ``tcp://host:port`` (also ``tls``, ``ucx``, ``ws``, ``wss``), ``inproc://...`` or
    ``host:port``; host a name, an IPv4 address or a bracketed IPv6 address, port 1..65535.
    Whether a scheduler answers there is the executor's question, at run time.
    """
    if any(form.fullmatch(address) for form in _SCHEDULER_FORMS):
        return None
    return (f"'{address}' is not a scheduler address (tcp://host:port, tls://host:port, "
            f"ucx://host:port, inproc://..., or host:port with a port in 1..65535)")


class InputSpec(_Strict):
    name: Text
    distribution: str
    mean: Number = None
    std: Number = None
    cv: Number = None
    lower: Number = None
    upper: Number = None
    mu: Number = None
    sigma: Number = None
    shape: Number = None
    scale: Number = None
    alpha: Number = None
    beta: Number = None
    units: str = ""

    @field_validator("distribution")
    @classmethod
    def _known(cls, v):
        if v not in DISTRIBUTIONS:
            raise ValueError(f"unknown distribution '{v}' (known: {', '.join(DISTRIBUTIONS)})")
        return v

    def parameters(self) -> dict:
        return self.model_dump(exclude={"name", "distribution", "units"}, exclude_none=True)


class CorrelationSpec(_Strict):
    inputs: list[Text] = Field(min_length=2)
    matrix: list[list[Float]]


class ExecutionSpec(_Strict):
    workers: Int = Field(2, ge=0, le=MAX_WORKERS,
                         description="dask worker processes; 0 runs in this process")
    scheduler: str | None = Field(None, description="address of an existing dask scheduler")
    seed: Int = Field(0, ge=0, le=MAX_SEED)
    batch: Annotated[int | None, BeforeValidator(_integer)] = Field(
        None, ge=1, le=MAX_REALIZATIONS, description="realizations per dask task")

    @field_validator("scheduler")
    @classmethod
    def _scheduler_form(cls, v):
        problem = None if v is None else scheduler_address_problem(v)
        if problem:
            raise ValueError(problem)
        return v
    max_failure_fraction: Float = Field(0.1, ge=0, le=1)
    checkpoint_interval: Float = Field(2.0, ge=0, description="seconds between result writes")


class OutputSpec(_Strict):
    path: Text | None = None
    figures: bool = Field(True, strict=True, description="write PNG figures beside the result")


class MethodSpec(BaseModel):
    model_config = ConfigDict(extra="allow")
    kind: str


class StudySpec(_Strict):
    name: Text
    description: str = ""
    solver: str
    scene: dict[str, Any] | str
    outputs: list[Text] | None = None
    inputs: list[InputSpec] = Field(default_factory=list)
    correlation: CorrelationSpec | None = None
    fields: list[dict[str, Any]] = Field(default_factory=list)
    method: MethodSpec
    levels: LevelsSpec | None = None
    # validated by uqflow.limit_states against the solver's outputs (its own one-line errors)
    limit_states: Any = None
    execution: ExecutionSpec = Field(default_factory=ExecutionSpec)
    output: OutputSpec = Field(default_factory=OutputSpec)

    @field_validator("scene", mode="before")
    @classmethod
    def _table_or_path(cls, v):
        if not isinstance(v, (dict, str)):
            raise ValueError("must be an inline table of scene options or the path of a "
                             f"scene file, got {shown_value(v)}")
        if isinstance(v, str) and not v.strip():
            raise ValueError("the path of a scene file must not be empty")
        return _visible(v) if isinstance(v, str) else v


@dataclass
class Study:
    """A validated study, ready to run."""

    spec: StudySpec
    path: Path
    text: str
    solver_class: type[Solver]
    scene: dict
    solver: Solver
    space: InputSpace
    method: PropagationMethod
    outputs: list[str]
    output_path: Path
    fields: list = field(default_factory=list)
    #: the other files the study reads, by the key naming them: {"scene": (path, sha256)}
    read_files: dict[str, tuple[str, str]] = field(default_factory=dict)
    #: fidelity levels (``[levels]``); ``scene`` and ``solver`` are then the finest level's
    levels: Levels | None = None
    #: keys set from outside the file (``uqflow run --set``), applied before validation
    overrides: dict[str, Any] = field(default_factory=dict)
    #: the failure events of ``[[limit_states]]`` (None without any)
    limit_states: LimitStates | None = None

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def sha256(self) -> str:
        """Provenance hash: the study text and the content of every file it reads (a scene
        file edited after a partial run must not resume into it)."""
        digest = hashlib.sha256(self.text.encode())
        for key in sorted(self.read_files):
            digest.update(f"\0{key}\0{self.read_files[key][1]}".encode())
        if self.overrides:  # a study without overrides keeps the hash it always had
            digest.update(f"\0--set\0{self.overrides_text}".encode())
        return digest.hexdigest()

    @property
    def overrides_text(self) -> str:
        """The overrides as TOML lines ``key = value``, in the order given ("" for none)."""
        return "".join(f"{key} = {toml_value(value)}\n" for key, value in self.overrides.items())


def _apply_overrides(document: dict, overrides: Mapping[str, Any]) -> tuple[dict, dict]:
    """The document with ``overrides`` set, and the overrides that reach into a scene file
    (``scene.<key>`` where ``scene`` names a file): those apply to the scene's table."""
    document = copy.deepcopy(document)
    into_scene = {}
    for key, value in overrides.items():
        parts = key_parts(key)
        if parts[0] == "scene" and len(parts) > 1 and isinstance(document.get("scene"), str):
            into_scene[".".join(parts[1:])] = value
        else:
            set_key(document, key, value)
    return document, into_scene


def _overridden(error: StudyError, overrides: Mapping[str, Any]) -> StudyError:
    """``error`` saying which override it comes from, when its key is (in or above) one."""
    if not overrides or error.key is None:
        return error
    mine = key_parts(error.key)
    for key, value in overrides.items():
        theirs = key_parts(key)
        n = min(len(mine), len(theirs))
        if mine[:n] == theirs[:n]:
            return type(error)(f"{error.reason} (from {SET_OPTION} {key}={toml_value(value)})",
                               file=error.file, key=error.key)
    return error


def read_toml(path: Path, file_label: str) -> tuple[dict, str]:
    """A TOML file (study or scene) and its text. UTF-8, with or without the byte-order mark
    some Windows editors write (TOML itself does not allow one)."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise StudyError("file not found", file=file_label) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise StudyError(f"cannot read: {exc}", file=file_label) from None
    try:
        return tomllib.loads(text), text
    except tomllib.TOMLDecodeError as exc:
        raise StudyError(f"not valid TOML: {exc}", file=file_label) from None


def load_study(path: str | Path, overrides: Mapping[str, Any] | None = None) -> Study:
    """Read, validate and resolve a study file; raise ``StudyError`` on any problem.

    ``overrides`` ({dotted key: value}, as ``uqflow run --set key=value`` gives them:
    ``{"method.samples": 64, "inputs.0.cv": 0.2}``) are set in the parsed file before it is
    validated, and validated exactly like it; an error they cause names the key and
    ``--set``. The study's text stays the file's; ``Study.overrides`` keeps them (the result
    records them, and its provenance hash covers them).
    """
    path = Path(path)
    label = str(path)
    overrides = dict(overrides or {})
    raw, text = read_toml(path, label)
    try:
        raw, scene_overrides = _apply_overrides(raw, overrides)
    except StudyError as exc:
        raise exc.located(label) from None
    try:
        spec = StudySpec.model_validate(raw)
    except ValidationError as exc:
        raise _overridden(validation_error(exc, label, data=raw, model=StudySpec),
                          overrides) from None
    try:
        # numpy's overflow warnings would print beside the one-line error (or the "ok"); every
        # value that matters is checked for finiteness instead.
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore", RuntimeWarning)
            study = _resolve(spec, path, text, label, scene_overrides)
    except StudyError as exc:  # SceneError too
        raise _overridden(exc.located(label), overrides) from None
    study.overrides = overrides
    return study


def _resolve(spec: StudySpec, path: Path, text: str, label: str,
             scene_overrides: Mapping[str, Any]) -> Study:
    folder = path.parent
    try:
        solver_class = get_solver(spec.solver)
    except StudyError as exc:
        raise StudyError(exc.reason, key="solver") from None

    scene, scene_label, scene_text = _load_scene(spec.scene, folder, label)
    if scene_overrides:
        scene = copy.deepcopy(scene)
        for key, value in scene_overrides.items():
            try:
                set_key(scene, key, value)
            except StudyError as exc:
                raise StudyError(f"scene.{exc.reason}", key=SET_OPTION) from None
    read_files = {} if scene_label is None else \
        {"scene": (scene_label, hashlib.sha256(scene_text.encode()).hexdigest())}
    try:
        if spec.levels is None:
            solver = solver_class.from_scene(scene)
        else:
            # the levels set their key: the scene is checked at the finest value, not at the
            # one it may hold for itself, and a value it refuses is the levels' fault
            finest = len(spec.levels.values) - 1
            solver = level_solver(spec.levels, scene, solver_class, finest)
            scene = scene_with(scene, spec.levels.key, spec.levels.values[finest])
    except SceneError as exc:
        raise SceneError(exc.reason, file=scene_label or label, key=exc.key) from None

    nominal = solver.nominal()
    for i, inp in enumerate(spec.inputs):
        if inp.name not in nominal:
            known = ", ".join(nominal) if len(nominal) <= 12 else \
                ", ".join(list(nominal)[:12]) + ", ..."
            raise StudyError(f"'{inp.name}' is not a parameter of this solver (it has {known})",
                             key=f"inputs[{i}].name")
    seen: dict[str, int] = {}
    for i, inp in enumerate(spec.inputs):
        if inp.name in seen:
            raise StudyError(f"input '{inp.name}' is declared twice "
                             f"(also inputs[{seen[inp.name]}])", key=f"inputs[{i}].name")
        seen[inp.name] = i
    inputs = []
    for i, inp in enumerate(spec.inputs):
        try:
            inputs.append(RandomInput.from_spec({"name": inp.name,
                                                 "distribution": inp.distribution,
                                                 "units": inp.units or
                                                 solver.parameter_units().get(inp.name, ""),
                                                 **inp.parameters()}))
        except StudyError as exc:
            field_name = (exc.key or "").rsplit(".", 1)[-1]
            raise StudyError(exc.reason, key=f"inputs[{i}].{field_name}") from None
    space = InputSpace(inputs, _correlation(spec, inputs))

    fields = _random_fields(spec, solver, label)

    template = solver.outputs()
    outputs = list(template.data_vars) if spec.outputs is None else list(spec.outputs)
    for i, name in enumerate(outputs):
        if name in outputs[:i]:
            raise StudyError(f"'{name}' is listed twice (also outputs[{outputs.index(name)}])",
                             key=f"outputs[{i}]")
        if name not in template.data_vars:
            raise StudyError(f"the solver has no output '{name}' "
                             f"(it has {', '.join(template.data_vars)})", key=f"outputs[{i}]")
    if not outputs:
        raise StudyError("at least one output is needed", key="outputs")

    try:
        method_class = get_method(spec.method.kind)
    except StudyError as exc:
        raise StudyError(exc.reason, key="method.kind") from None
    options = {k: v for k, v in (spec.method.model_extra or {}).items()}
    try:
        method = method_class(**options)
    except ValidationError as exc:
        raise validation_error(exc, label, prefix="method", data=options,
                               model=getattr(method_class, "Options", None),
                               extra_known=("kind",)) from None
    except StudyError as exc:
        raise StudyError(exc.reason, key=exc.key or "method") from None
    if not spec.inputs and not spec.fields and method.needs_inputs:
        raise StudyError("a study needs at least one uncertain input: add an [[inputs]] or "
                         "a [[fields]] table (or use kind = \"nominal\" for one deterministic "
                         "run)", key="inputs")
    method.check(space, fields)
    method.check_solver(solver, outputs, space.names)
    limit_states = _limit_states(spec, template, outputs, label)
    method.check_limit_states(limit_states)
    levels = _levels(spec, method, scene, solver_class, outputs, scene_label or label)
    if levels is not None:
        scene, solver = levels.scenes[-1], levels.solvers[-1]

    out = spec.output.path or f"results/{spec.name}.nc"
    output_path = (folder / out).resolve() if not Path(out).is_absolute() else Path(out)
    if output_path.suffix != ".nc":
        raise StudyError(f"a result file ends in .nc, got '{out}'", key="output.path")
    return Study(spec=spec, path=path, text=text, solver_class=solver_class, scene=scene,
                 solver=solver, space=space, method=method, outputs=outputs,
                 output_path=output_path, fields=fields, read_files=read_files,
                 levels=levels, limit_states=limit_states)


def _limit_states(spec: StudySpec, template, outputs: list[str],
                  label: str) -> LimitStates | None:
    """The study's [[limit_states]], checked against the outputs it stores."""
    if spec.limit_states is None:
        return None
    try:
        return LimitStates.from_tables(spec.limit_states, template[outputs], label)
    except StudyError as exc:
        which = re.fullmatch(r"limit_states\[(\d+)\]\.output", exc.key or "")
        named = spec.limit_states[int(which.group(1))].get("output") if which else None
        if isinstance(named, str) and named in template.data_vars:
            raise StudyError(f"'{named}' is an output of the solver but not of this study: "
                             f"add it to outputs", file=exc.file, key=exc.key) from None
        raise


def _levels(spec: StudySpec, method, scene: dict, solver_class, outputs: list[str],
            scene_label: str) -> Levels | None:
    """The study's fidelity levels, checked against what its method does with them."""
    uses = getattr(method, "uses_levels", False)
    if spec.levels is None:
        if uses:
            raise StudyError(f"method '{spec.method.kind}' runs the solver at several "
                             f"fidelities: add a [levels] table (key, values)", key="levels")
        return None
    if not uses:
        raise StudyError(f"method '{spec.method.kind}' does not use fidelity levels: drop "
                         f"[levels], or use kind = \"multilevel\" or \"multifidelity\"",
                         key="levels")
    levels = resolve_levels(spec.levels, scene, solver_class, outputs, scene_label)
    method.check_levels(levels)
    return levels


def _random_fields(spec: StudySpec, solver: Solver, label: str) -> list:
    """Validate the [[fields]] tables and build their KL bases on the solver's points."""
    if not spec.fields:
        return []
    from uqflow.fields import FieldSpec, RandomField

    fields, driven = [], {}
    for i, raw in enumerate(spec.fields):
        try:
            fspec = FieldSpec.model_validate(raw)
        except ValidationError as exc:
            raise validation_error(exc, label, prefix=f"fields[{i}]") from None
        if fspec.name in (f.name for f in fields):
            raise StudyError(f"field '{fspec.name}' is declared twice", key=f"fields[{i}].name")
        points = None
        for j, target in enumerate(fspec.targets):
            where = f"fields[{i}].parameters[{j}]" if fspec.parameters else f"fields[{i}].name"
            if target in driven:
                raise StudyError(f"'{target}' is already driven by field '{driven[target]}'",
                                 key=where)
            try:
                target_points = np.asarray(solver.field_points(target), dtype=float)
            except SceneError as exc:
                raise StudyError(exc.reason, key=where) from None
            points = target_points if points is None else points
            driven[target] = fspec.name
        try:
            fields.append(RandomField(fspec, points))
        except ArithmeticError:
            # The KL eigenproblem in float64 (e.g. exp(-L/b) with b ~ 1e300 times the domain).
            raise StudyError(f"the KL basis cannot be built in float64 with correlation_length "
                             f"{fspec.correlation_length:g} m on this domain",
                             key=f"fields[{i}].correlation_length") from None
        except (ValueError, StudyError) as exc:
            raise StudyError(str(getattr(exc, "reason", exc)), key=f"fields[{i}]") from None
    return fields


def _load_scene(scene, folder: Path, label: str) -> tuple[dict, str | None, str | None]:
    """The scene table, the scene file's path and its text (both None for an inline table)."""
    if isinstance(scene, dict):
        return scene, None, None
    scene_path = folder / scene
    if not scene_path.is_file():
        what = "is a folder, not a scene file" if scene_path.is_dir() else "no such scene file"
        raise StudyError(f"{what}: {scene_path}", key="scene")
    raw, text = read_toml(scene_path, str(scene_path))
    return raw, str(scene_path), text


def _correlation(spec: StudySpec, inputs: list[RandomInput]) -> np.ndarray | None:
    corr = spec.correlation
    if corr is None:
        return None
    names = [i.name for i in inputs]
    for j, name in enumerate(corr.inputs):
        if name not in names:
            raise StudyError(f"'{name}' is not one of the study's inputs",
                             key=f"correlation.inputs[{j}]")
    for j, name in enumerate(corr.inputs):
        if name in corr.inputs[:j]:
            raise StudyError(f"'{name}' is named twice", key=f"correlation.inputs[{j}]")
    m = len(corr.inputs)
    sub = np.asarray(corr.matrix, dtype=float) if all(len(r) == m for r in corr.matrix) \
        else None
    if sub is None or sub.shape != (m, m):
        raise StudyError(f"must be {m}x{m}, one row per name in correlation.inputs",
                         key="correlation.matrix")
    full = np.eye(len(inputs))
    idx = [names.index(n) for n in corr.inputs]
    full[np.ix_(idx, idx)] = sub
    from uqflow.inputs import check_correlation
    check_correlation(full, len(inputs))
    return full
