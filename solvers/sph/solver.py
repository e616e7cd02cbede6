"""The corrected-SPH composite solver as a uqflow Solver (seed 001; docs/sph.md)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import xarray as xr

from solvers.sph import exact
from solvers.sph.constraints import ConstraintError
from solvers.sph.interpolation import InterpolationError
from solvers.sph.linear import LinearSolveError
from solvers.sph.loading import run_tension
from solvers.sph.problem import ElasticProblem
from solvers.sph.report import report as composite_report
from solvers.sph.scene import MAX_STIFFNESS, Config, parse, stiffness_scale
from solvers.sph.scene_layout import scene_layout, support_diameter
from solvers.sph.stiffness import Discretisation
from solvers.sph.symbolic import SymbolicStore
from uqflow.errors import SceneError, SolverError
from uqflow import layout as result_layout
from uqflow.solver import Solver, register_solver

UNITS = {"matrix.E": "Pa", "matrix.nu": "", "inclusion.E": "Pa", "inclusion.nu": "",
         "interface.strength": "Pa", "load.eigenstrain": ""}
FIELDS = ("matrix.E", "inclusion.E", "interface.strength")
#: outputs that describe the computation, not the composite: the Solver contract's
#: ``output_kind = "diagnostic"`` (stored in the runs; no statistics, figures or allocation)
DIAGNOSTICS = ("particles", "constraint_residual", "pair_error", "time_neighbours",
               "time_assembly", "time_transformation", "time_solve")
#: every output's SI units and its name in words (CF ``units`` and ``long_name``)
OUTPUTS = {
    "volume_fraction": ("1", "inclusion volume fraction"),
    "particles": ("1", "number of particles"),
    "constraint_residual": ("m", "largest residual of the imposed constraints"),
    "pair_error": ("1", "largest displacement jump across an intact interface pair, relative "
                        "to the largest displacement"),
    "time_neighbours": ("s", "time of the neighbour search"),
    "time_assembly": ("s", "time of the stiffness assembly"),
    "time_transformation": ("s", "time of the master–slave transformation"),
    "time_solve": ("s", "time of the linear solves"),
    "x": ("m", "particle position"),
    "displacement": ("m", "displacement"),
    "stress": ("Pa", "stress"),
    "pair_break_step": ("1", "load step at which the interface pair breaks (0: never)"),
    "strain": ("1", "applied strain"),
    "macro_stress": ("Pa", "mean tensile stress σ_yy of the plate"),
    "intact_pairs": ("1", "intact interface pairs"),
    "detached_inclusions": ("1", "fully debonded inclusions"),
    "effective_modulus": ("Pa", "apparent Young's modulus"),
    "modulus_reuss_bound": ("Pa", "Reuss (lower) bound of the apparent Young's modulus"),
    "modulus_voigt_bound": ("Pa", "Voigt (upper) bound of the apparent Young's modulus"),
    "modulus_hs_lower": ("Pa", "Hashin–Shtrikman lower bound of the effective Young's "
                               "modulus"),
    "modulus_hs_upper": ("Pa", "Hashin–Shtrikman upper bound of the effective Young's "
                               "modulus"),
    "inclusion_detach_step": ("1", "load step at which the inclusion fully debonds (0: never)"),
    "debonding_onset_strain": ("1", "applied strain of the load step at which the first "
                                    "interface pair breaks (one step past the loading: none "
                                    "within it)"),
    "detachment_onset_strain": ("1", "applied strain of the load step at which the first "
                                     "inclusion fully debonds (one step past the loading: none "
                                     "within it)"),
}
#: outputs that take discrete values: steps, counts, and the applied strain of a load step
DISCRETE = ("pair_break_step", "intact_pairs", "detached_inclusions", "inclusion_detach_step",
            "debonding_onset_strain", "detachment_onset_strain")
#: the applied strain at which an event happens, with the strain past the loading for none
ONSETS = ("debonding_onset_strain", "detachment_onset_strain")


@register_solver("sph")
class SPHSolver(Solver):
    """Quasi-static corrected SPH of a particulate composite with master–slave constraints."""

    #: solve the system after a break through a low-rank update of the last one's factors
    #: (factor_update.py); False factorises it afresh, the solver before (for the benchmark)
    update_factors = True

    def __init__(self, cfg: Config):
        self.cfg = cfg
        self.layout = self._layout(None)
        self.disc = self._discretise(self.layout)
        self._template = self._make_template()
        #: the realizations on the fixed layout hand each other their first system's order
        #: or PARDISO analysis (solvers/sph/symbolic.py); a random layout's differ
        self.symbolic = SymbolicStore() if cfg.layout != "random" else None

    # -- construction ----------------------------------------------------------------------

    @classmethod
    def from_scene(cls, scene: Mapping) -> "SPHSolver":
        cfg = parse(scene)
        gap = cfg.random.min_gap if cfg.random is not None else None
        if gap is not None:
            support = support_diameter(cfg)
            if gap < support:
                raise SceneError(f"{gap:.4g} m is below one support diameter ({support:.4g} m "
                                 f"at spacing {cfg.spacing:.4g} m): supports of two inclusions "
                                 f"would meet", key="scene.random.min_gap")
        return cls(cfg)

    def _layout(self, seed):
        return scene_layout(self.cfg, seed)

    def _discretise(self, layout):
        try:
            return Discretisation(layout, self.cfg.smoothing_ratio, self.cfg.kernel)
        except InterpolationError as e:
            raise SceneError(str(e), key="scene.smoothing_ratio") from None

    @classmethod
    def report(cls, trees: list, folder, figures: bool = True) -> tuple[str, list]:
        """A map of each result's scene (``scene_map.png``); for tension results the moduli
        against their bounds, the stress–strain envelope and full debonding
        (solvers/sph/report.py, docs/sph.md § 10)."""
        return composite_report(trees, folder, figures)

    def describe(self) -> str:
        c = self.cfg
        return (f"sph/{c.layout} {self.layout.x.shape[0]} particles, {c.constraints}, "
                f"{c.loading}")

    # -- contract --------------------------------------------------------------------------

    def nominal(self) -> dict[str, float]:
        c = self.cfg
        return {"matrix.E": c.matrix[0], "matrix.nu": c.matrix[1], "inclusion.E": c.inclusion[0],
                "inclusion.nu": c.inclusion[1], "interface.strength": c.interface_strength,
                "load.eigenstrain": c.eigenstrain}

    def parameter_units(self) -> dict[str, str]:
        return dict(UNITS)

    def field_points(self, name: str) -> np.ndarray:
        """Particles of the matrix (``matrix.E``) or of the inclusions (``inclusion.E``), or the
        interface pairs (``interface.strength``), of the nominal layout (m)."""
        lay = self.layout
        if name == "matrix.E":
            return lay.x[lay.phase == 0]
        if name == "inclusion.E":
            return lay.x[lay.phase > 0]
        if name == "interface.strength":
            return lay.x[np.asarray(lay.pairs)[:, 0]]
        return super().field_points(name)

    def outputs(self) -> xr.Dataset:
        return self._template.copy(deep=True)

    def _make_template(self) -> xr.Dataset:
        c = self.cfg
        nan = np.nan
        data = {name: ((), nan) for name in ("volume_fraction", *DIAGNOSTICS)}
        coords = {}
        fixed = c.layout != "random"
        if fixed:
            n, npair = self.layout.x.shape[0], np.asarray(self.layout.pairs).shape[0]
            data.update({"x": (("particle", "component"), np.full((n, 2), nan)),
                         "displacement": (("particle", "component"), np.full((n, 2), nan)),
                         "stress": (("particle", "voigt"), np.full((n, 3), nan))})
            coords.update({"particle": np.arange(n), "component": ["x", "y"],
                           "voigt": ["xx", "yy", "xy"]})
            if c.loading == "tension":
                data["pair_break_step"] = (("pair",), np.full(npair, nan))
                coords["pair"] = np.arange(npair)
        if c.loading == "tension":
            n_incl = len(self.layout.inclusions)
            per_step = (("step",), np.full(c.steps, nan))
            data.update({name: per_step for name in ("strain", "macro_stress", "intact_pairs",
                                                     "detached_inclusions")})
            data.update({name: ((), nan) for name in (
                "effective_modulus", "modulus_reuss_bound", "modulus_voigt_bound",
                "modulus_hs_lower", "modulus_hs_upper")})
            data["inclusion_detach_step"] = (("inclusion",), np.full(n_incl, nan))
            data.update({name: ((), nan) for name in ONSETS})
            coords.update({"step": np.arange(1, c.steps + 1), "inclusion": np.arange(n_incl)})
        ds = xr.Dataset({name: xr.Variable(dims, values, output_attributes(name))
                         for name, (dims, values) in data.items()}, coords=coords)
        if c.loading == "tension":
            beyond = strain_past_loading(self.layout, c.step, c.steps)
            for name in ONSETS:
                ds[name].attrs[result_layout.NOT_WITHIN_LOADING] = beyond
        return ds

    # -- one realization -------------------------------------------------------------------

    def _parameters(self, params):
        p = self.nominal()
        for name, value in params.items():
            if name not in p:
                raise SolverError(f"unknown parameter '{name}' (known: {', '.join(p)})")
            try:
                p[name] = float(value)
            except (TypeError, ValueError):
                raise SolverError(f"parameter '{name}' is not a number: {value!r}") from None
        for phase in ("matrix", "inclusion"):
            if not p[f"{phase}.E"] > 0:
                raise SolverError(f"{phase}.E = {p[f'{phase}.E']!r} is not > 0")
            if not 0.0 < p[f"{phase}.nu"] < 0.5:
                raise SolverError(f"{phase}.nu = {p[f'{phase}.nu']!r} is not in (0, 0.5)")
            if not stiffness_scale(p[f"{phase}.E"], p[f"{phase}.nu"]) <= MAX_STIFFNESS:
                raise SolverError(f"{phase}.E = {p[f'{phase}.E']!r} with nu = "
                                  f"{p[f'{phase}.nu']!r} gives lambda + 2 mu above "
                                  f"{MAX_STIFFNESS:g} Pa: the stiffness would overflow")
        if not p["interface.strength"] > 0:
            raise SolverError(f"interface.strength = {p['interface.strength']!r} is not > 0")
        return p

    def run(self, params: Mapping[str, float] | None = None, fields=None,
            seed: int | None = None) -> xr.Dataset:
        c = self.cfg
        p = self._parameters(dict(params or {}))
        if c.layout == "random" and seed is not None:
            try:
                layout = self._layout(seed)
                disc = self._discretise(layout)
            except SceneError as e:
                raise SolverError(f"layout of seed {seed}: {e}") from None
        else:
            layout, disc = self.layout, self.disc
        inside = layout.phase > 0
        E = np.where(inside, p["inclusion.E"], p["matrix.E"])
        nu = np.where(inside, p["inclusion.nu"], p["matrix.nu"])
        strength = np.full(np.asarray(layout.pairs).shape[0], p["interface.strength"])
        if fields is not None:
            E[~inside] = _field(fields, "matrix.E", layout.x[~inside], p["matrix.E"], "Pa")
            E[inside] = _field(fields, "inclusion.E", layout.x[inside], p["inclusion.E"], "Pa")
            strength = _field(fields, "interface.strength",
                              layout.x[np.asarray(layout.pairs)[:, 0]], p["interface.strength"],
                              "Pa", default=strength)
        eigen, eigen_zz = None, None
        if c.loading == "eigenstrain":
            eps = p["load.eigenstrain"]
            eigen = np.zeros((layout.x.shape[0], 3))
            eigen[inside, :2] = eps
            if c.eigenstrain_mode == "dilatation_3d":
                eigen_zz = np.where(inside, eps, 0.0)
        radius = None if c.cutoff_radius is None else c.cutoff_radius * disc.radius
        try:
            problem = ElasticProblem(disc, E, nu, c.state, eigenstrain=eigen,
                                     eigenstrain_zz=eigen_zz, method=c.constraints,
                                     integration=c.integration, penalty=c.penalty,
                                     cutoff_threshold=c.cutoff_threshold, cutoff_radius=radius,
                                     min_support=c.min_support, linear_solver=c.linear_solver,
                                     stabilisation=c.stabilisation,
                                     update_factors=self.update_factors,
                                     symbolic=self.symbolic)
            if c.loading == "tension":
                out = self._tension(problem, layout, strength)
                out.update(_bounds(layout, E, nu, c.state))
            else:
                out = self._eigenstrain(problem, layout, p)
        except (ConstraintError, LinearSolveError, InterpolationError) as e:
            raise SolverError(str(e)) from None
        ds = self._template.copy(deep=True)
        out["volume_fraction"] = layout.volume_fraction
        out["particles"] = layout.x.shape[0]
        for name, value in out.items():
            if name in ds:
                var = ds.variables[name]
                var.values = np.asarray(value, dtype=float).reshape(var.shape)
        if c.layout != "random":
            ds["x"].values = layout.x
        return ds

    def _timings(self, timings):
        return {f"time_{k}": v for k, v in timings.items()}

    def _tension(self, problem, layout, strength):
        c = self.cfg
        h = run_tension(problem, layout, strength, c.step, c.steps)
        out = onset_strains(h, strain_past_loading(layout, c.step, c.steps))
        out.update({"strain": h.strain, "macro_stress": h.macro_stress,
                   "intact_pairs": h.intact_pairs, "detached_inclusions": h.detached_inclusions,
                   "effective_modulus": h.effective_modulus,
                   "inclusion_detach_step": h.inclusion_detach_step,
                   "constraint_residual": float(h.constraint_residual.max()),
                   "pair_error": float(h.pair_error.max()),
                   "pair_break_step": h.pair_break_step,
                   # a detached inclusion carries no stress and its rigid position is
                   # undetermined: reported as 0 (results hold no NaN: uqflow counts a NaN
                   # output as a failure)
                   "displacement": np.nan_to_num(h.last.displacement, nan=0.0),
                   "stress": np.nan_to_num(h.last.stress, nan=0.0)})
        out.update(self._timings(h.timings))
        return out

    def _eigenstrain(self, problem, layout, p):
        c = self.cfg
        boundary = np.asarray(layout.boundary)
        if c.edge == "fixed":
            values = np.zeros((boundary.size, 2))
        else:
            values = exact.eshelby_displacement(
                layout.x[boundary], radius=c.inclusions[0].semi_axes[0],
                centre=c.inclusions[0].centre, eigenstrain=p["load.eigenstrain"],
                E_inclusion=p["inclusion.E"], nu_inclusion=p["inclusion.nu"],
                E_matrix=p["matrix.E"], nu_matrix=p["matrix.nu"],
                variant=_variant(c))
        sol = problem.solve(values)
        timings = dict(problem.setup_timings)
        for k, v in sol.timings.items():
            timings[k] = timings.get(k, 0.0) + v
        out = {"displacement": sol.displacement, "stress": sol.stress,
               "constraint_residual": sol.constraint_residual, "pair_error": sol.pair_error}
        out.update(self._timings(timings))
        return out


def output_attributes(name: str) -> dict:
    """An output's ``units``, ``long_name`` and, for a diagnostic, its ``output_kind``; for
    a step, a count or an onset ``output_values = discrete`` (a limit state on it counts
    events and has no gradient)."""
    units, long_name = OUTPUTS[name]
    kind = {result_layout.OUTPUT_KIND: result_layout.DIAGNOSTIC_KIND} if name in DIAGNOSTICS \
        else {}
    if name in DISCRETE:
        kind[result_layout.OUTPUT_VALUES] = result_layout.DISCRETE_VALUES
    return {result_layout.UNITS: units, result_layout.LONG_NAME: long_name, **kind}


def onset_strains(history, beyond: float) -> dict[str, float]:
    """The applied strain of the load step where the first pair broke and where the first
    inclusion detached (``history``: a ``TensionHistory``), ``beyond`` where none did."""
    broke = history.pair_break_step[history.pair_break_step > 0]
    detached = history.inclusion_detach_step[history.inclusion_detach_step > 0]
    return {"debonding_onset_strain": float(history.strain[broke.min() - 1]) if broke.size
            else beyond,
            "detachment_onset_strain": float(history.strain[detached.min() - 1])
            if detached.size else beyond}


def strain_past_loading(layout, step: float, steps: int) -> float:
    """The applied strain of load step ``steps + 1``, the one after the loading: an onset
    that did not happen within the loading is reported as this (finite, above every strain
    the loading reaches; computed as ``run_tension`` computes a step's strain)."""
    y = np.asarray(layout.x, dtype=float)[:, 1]
    return 2.0 * step * (steps + 1) / float(y.max() - y.min())


def _bounds(layout, E, nu, state) -> dict:
    """Bounds of the apparent in-plane Young's modulus of this window.

    Voigt–Reuss (area averages of the particles' own moduli) bound it for every arrangement
    of the phases under the tension test's boundary conditions. Hashin–Shtrikman, for the
    window's volume fraction, bound the *effective* modulus of a statistically isotropic
    composite, which only the ensemble of windows estimates (docs/sph.md § 8); with moduli
    varying over the particles (fields) the HS lower bound takes each phase's softest and
    the upper its stiffest (HS bounds grow with the phase moduli)."""
    inside = layout.phase > 0
    reuss, voigt = exact.voigt_reuss_2d(layout.volume, E, nu, state)
    lo = exact.hashin_shtrikman_2d(layout.volume_fraction, E[inside].min(),
                                   nu[inside].mean(), E[~inside].min(), nu[~inside].mean(),
                                   state)["E_2D"][0]
    hi = exact.hashin_shtrikman_2d(layout.volume_fraction, E[inside].max(),
                                   nu[inside].mean(), E[~inside].max(), nu[~inside].mean(),
                                   state)["E_2D"][1]
    return {"modulus_reuss_bound": reuss, "modulus_voigt_bound": voigt,
            "modulus_hs_lower": float(lo), "modulus_hs_upper": float(hi)}


def _variant(c: Config) -> str:
    if c.state == "plane_stress":
        return "plane_stress"
    return "plane_strain_3d" if c.eigenstrain_mode == "dilatation_3d" else "plane_strain"


def _field(fields, name, points, mean, unit, default=None):
    """The realization's field ``name`` at ``points``, or ``default``/``mean`` where no field
    drives it; SolverError where a value is not finite and > 0."""
    try:
        driven = name in fields
    except TypeError:
        driven = False
    if not driven:
        return np.full(points.shape[0], float(mean)) if default is None else default
    vals = np.asarray(fields.values(name, points, mean, 0.0, np.inf), dtype=float).reshape(-1)
    bad = ~(np.isfinite(vals) & (vals > 0))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise SolverError(f"{name} is not > 0 at point {i} ({points[i, 0]:.6g}, "
                          f"{points[i, 1]:.6g}) m: {vals[i]!r} {unit}")
    return vals
