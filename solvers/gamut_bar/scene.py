"""The gamut-bar scene: its keys declared as a pydantic model, as the study file is.

``BarScene`` declares every key with its type, default and bounds; ``parse_scene(scene)``
validates a scene table and returns the solver's configuration and the nominal material
(``(cfg, props)``, SI). A key of the wrong type or outside its bounds is a one-line
``SceneError`` naming ``scene.<key>`` (pydantic's error turned into one line by
``uqflow.validation.validation_error``, the study file's own adapter); what depends on several keys
(the material's consistency, the bond count, the cyclic load steps) is checked after, and
names the key to change. The reference for users is docs/gamut_bar.md, "Scene".
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Literal

import numpy as np
from pydantic import (BaseModel, BeforeValidator, ConfigDict, Field, ValidationError,
                      field_validator)

from solvers.gamut_bar.materials import MATERIALS, material_problem, overflow_problem, ro_stress
from uqflow.errors import SceneError
from uqflow.validation import validation_error

#: material properties a scene may override (SI); R overrides eq. 18's modulus of softness
PROPERTIES = ("E", "sigma_y", "sigma_f", "eps_f", "n_ro", "K_ro", "rho", "nu", "R", "area",
              "length")
#: the bar's cross-section (m2) and length (m) where the scene does not set them
AREA, LENGTH = 1.0e-4, 0.1

# Upper bounds of the counts, so that what validates can run (docs/study-files.md, "Limits").
# Every load step solves the whole network (local + nonlocal bonds) by Newton: the seed's bar
# has 500 local bonds and 23 families (12,000 bonds); a bond keeps a few tens of float64, so
# 10^7 bonds are of the order of a GiB of state.
MAX_LOCAL_BONDS = 10**6
MAX_FAMILIES = 10**3         # nonlocal degrees 2..cutoff × sigma_stdev
MAX_BONDS = 10**7            # local bonds × (1 + families)
MAX_LOAD_STEPS = 10**6       # recorded load steps of one curve (monotonic or cyclic)
MAX_CYCLES = 10**3           # amplitudes of a cyclic test
MAX_CYCLE_REPEATS = 10**3
MIN_CYCLIC_INCREMENT = 1e-4  # 10^4 load steps per quarter cycle at most
MAX_BISECTIONS = 100         # halvings of the failure-load bracket (float64 resolves ~53)
MAX_GRID_SEED = 2**64 - 1    # numpy's generators take any; keep it a 64-bit number


def _number(value):
    # A TOML boolean is never a number; numpy scalars (a scene built in Python) are plain ones.
    if isinstance(value, bool):
        raise ValueError(f"must be a number, got {str(value).lower()}")
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    return value


def _integer(value):
    value = _number(value)
    if isinstance(value, float) and value.is_integer():
        raise ValueError(f"must be an integer: write {value:.0f}, not {value!r}")
    return value


Number = Annotated[float, BeforeValidator(_number)]
Integer = Annotated[int, BeforeValidator(_integer)]
Positive = Annotated[float, BeforeValidator(_number), Field(gt=0)]
Material = Literal[tuple(MATERIALS)]


class BarScene(BaseModel):
    """The keys of a gamut-bar scene (docs/gamut_bar.md, "Scene")."""

    # Strict: an integer key takes an integer only, a number an integer or a float; no NaN
    # or infinity anywhere, no key that is not declared.
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)

    material: Material = "M1"
    grid: Literal["uniform", "stochastic"] = "uniform"
    loading: Literal["monotonic", "cyclic"] = "monotonic"
    # material overrides (None: the material's value, or eq. 18 for R)
    E: Positive | None = None
    sigma_y: Positive | None = None
    sigma_f: Positive | None = None
    eps_f: Positive | None = None
    n_ro: Annotated[float, BeforeValidator(_number), Field(gt=1)] | None = None
    K_ro: Positive | None = None
    rho: Positive | None = None
    nu: Number | None = None
    R: Annotated[float, BeforeValidator(_number), Field(gt=0, lt=1)] | None = None
    area: Positive | None = None
    length: Positive | None = None
    # the bar and its nonlocal bonds
    local_bonds: Integer = Field(500, ge=2, le=MAX_LOCAL_BONDS)
    grid_factor: Number = Field(0.65, ge=0)
    min_spacing_fraction: Number = Field(0.05, gt=0, le=0.99)
    grid_seed: Integer = Field(0, ge=0, le=MAX_GRID_SEED)
    sigma_stdev: Positive = 8.0
    cutoff: Positive = 3.0
    # loading
    curve_points: Integer = Field(400, ge=2, le=MAX_LOAD_STEPS)
    cycles: Integer = Field(10, ge=2, le=MAX_CYCLES)
    cycle_repeats: Integer = Field(2, ge=1, le=MAX_CYCLE_REPEATS)
    amplitude_range: list[Positive] = Field([1.0, 1.1], min_length=2, max_length=2)
    initial_force: Positive = 0.01
    force_growth: Annotated[float, BeforeValidator(_number), Field(gt=1)] = 1.01
    cyclic_increment: Number = Field(0.01, ge=MIN_CYCLIC_INCREMENT, le=0.5)
    bisections: Integer = Field(30, ge=1, le=MAX_BISECTIONS)

    @field_validator("cyclic_increment")
    @classmethod
    def _one_over_integer(cls, value):
        if abs(1.0 / value - round(1.0 / value)) > 1e-9:
            raise ValueError("must be 1/integer (e.g. 0.01)")
        return value

    @field_validator("amplitude_range")
    @classmethod
    def _increasing(cls, value):
        if value[0] >= value[1]:
            raise ValueError(f"low must be below high, got {value!r}")
        return value


#: the scene's keys and their defaults (what an empty scene means)
DEFAULTS = {**{k: v for k, v in BarScene().model_dump().items() if v is not None},
            "area": AREA, "length": LENGTH}
SCENE_KEYS = frozenset(BarScene.model_fields)


def _declared(scene) -> BarScene:
    if not isinstance(scene, Mapping):
        raise SceneError("must be a table", key="scene")
    raw = dict(scene)
    if "eps_y" in raw:    # the seed lists it among the properties; here it follows from others
        raise SceneError("is derived (sigma_y/E + K_ro); set E, sigma_y or K_ro",
                         key="scene.eps_y")
    try:
        return BarScene.model_validate(raw)
    except ValidationError as exc:
        err = validation_error(exc, "", prefix="scene", data=raw, model=BarScene)
        raise SceneError(err.reason, key=err.key) from None


def parse_scene(scene) -> tuple[dict, dict]:
    """The solver's configuration and the nominal material (SI) of a scene table; a
    ``SceneError`` naming ``scene.<key>`` for anything it cannot run."""
    s = _declared(scene)
    cfg = {"material": s.material, "grid": s.grid, "loading": s.loading}
    props = dict(MATERIALS[s.material], area=AREA, length=LENGTH)
    given = {k: getattr(s, k) for k in PROPERTIES if getattr(s, k) is not None}
    props.update({k: float(v) for k, v in given.items()})
    problem, R_eq18 = material_problem(props)
    if problem:
        raise SceneError(problem[1], key=f"scene.{problem[0]}")
    if "R" not in given:
        props["R"] = R_eq18
    cfg["R_given"] = "R" in given
    cfg["local_bonds"] = s.local_bonds
    cfg["grid_factor"] = float(s.grid_factor)
    cfg["min_spacing_fraction"] = float(s.min_spacing_fraction)
    if 1.0 + cfg["grid_factor"] <= cfg["min_spacing_fraction"]:
        raise SceneError("no spacing can be drawn above it (1 + grid_factor)",
                         key="scene.min_spacing_fraction")
    cfg["grid_seed"] = s.grid_seed
    cfg["sigma_stdev"] = float(s.sigma_stdev)
    cfg["cutoff"] = float(s.cutoff)
    _check_bonds(cfg)
    cfg["curve_points"] = s.curve_points
    cfg["cycles"] = s.cycles
    cfg["cycle_repeats"] = s.cycle_repeats
    cfg["amplitude_range"] = (float(s.amplitude_range[0]), float(s.amplitude_range[1]))
    _check_amplitudes(cfg["amplitude_range"], props)
    cfg["initial_force"] = float(s.initial_force)
    cfg["force_growth"] = float(s.force_growth)
    cfg["cyclic_increment"] = float(s.cyclic_increment)
    cfg["bisections"] = s.bisections
    if cfg["loading"] == "cyclic":
        _check_cyclic_steps(cfg)
    return cfg, props


def _check_bonds(cfg):
    spacings = cfg["cutoff"] * cfg["sigma_stdev"]
    if spacings < 2.0:
        raise SceneError(f"cutoff × sigma_stdev = {spacings:g} spacings: no nonlocal bond "
                         f"(degree ≥ 2) within it", key="scene.cutoff")
    families = spacings - 1
    if families > MAX_FAMILIES:
        raise SceneError(f"cutoff × sigma_stdev = {spacings:g} spacings make {families:g} "
                         f"bond families; at most {MAX_FAMILIES:,}", key="scene.cutoff")
    bonds = cfg["local_bonds"] * (1 + families)
    if bonds > MAX_BONDS:
        raise SceneError(f"{cfg['local_bonds']:,} local bonds × {1 + families:g} (1 + families) "
                         f"= {bonds:.3g} bonds; at most {MAX_BONDS:.0e}",
                         key="scene.local_bonds")


def _check_amplitudes(amplitude_range, props):
    try:
        top = ro_stress(props["eps_f"], props["E"], props["sigma_y"], props["n_ro"],
                        props["K_ro"])
    except OverflowError:
        key, reason = overflow_problem(props)
        raise SceneError(reason, key=f"scene.{key}") from None
    if amplitude_range[1] * props["sigma_y"] >= top:
        raise SceneError(f"the highest amplitude {amplitude_range[1] * props['sigma_y']:.4g} Pa "
                         f"is not below the stress at the failure strain ({top:.4g} Pa)",
                         key="scene.amplitude_range")


def _check_cyclic_steps(cfg):
    # Each repeat of each amplitude is a loop of 2 × (2 / increment) steps.
    loops = cfg["cycles"] * cfg["cycle_repeats"]
    steps = loops * 4.0 / cfg["cyclic_increment"]
    if steps > MAX_LOAD_STEPS:
        raise SceneError(f"{loops:,} loops (cycles × cycle_repeats) of "
                         f"{4 / cfg['cyclic_increment']:.0f} steps are {steps:.3g} load steps; "
                         f"at most {MAX_LOAD_STEPS:.0e}", key="scene.cyclic_increment")

