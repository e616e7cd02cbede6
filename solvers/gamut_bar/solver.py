"""The deformation-gamut bar as a uqflow Solver (seed 002; docs/gamut_bar.md)."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import xarray as xr

from solvers.gamut_bar import kernels as K
from solvers.gamut_bar.loading import (CyclicPlan, fit_cyclic, loop_amplitudes,
                                       monotonic_forces, resample_path)
from solvers.gamut_bar.materials import calibrate, family_weights, material_problem
from solvers.gamut_bar.network import (bond_weights, build_network, effective_sigma,
                                       grid_correction, nonlocal_bonds, stochastic_grid,
                                       uniform_grid)
from solvers.gamut_bar.report import report as _report
from solvers.gamut_bar.scene import parse_scene
from uqflow.errors import SolverError
from uqflow.layout import (DIAGNOSTIC_KIND, DISCRETE_VALUES, FLAG_MEANINGS, FLAG_VALUES,
                           LONG_NAME, NO_VALUE_REASON, NOT_WITHIN_LOADING, OUTPUT_KIND,
                           OUTPUT_VALUES, UNDEFINED_WHEN, UNITS)
from uqflow.solver import Solver, register_solver

PARAMETERS = ("bar.E", "bar.R", "bar.w", "bar.rho", "bar.sigma_y", "bar.sigma_f", "bar.eps_f",
              "bar.n_ro", "bar.K_ro", "bar.area", "bar.length")
PARAMETER_UNITS = {"bar.E": "Pa", "bar.R": "", "bar.w": "", "bar.rho": "kg m-3", "bar.sigma_y": "Pa",
         "bar.sigma_f": "Pa", "bar.eps_f": "", "bar.n_ro": "", "bar.K_ro": "",
         "bar.area": "m2", "bar.length": "m"}      # "" where dimensionless (Solver contract)
FIELDS = ("bar.E", "bar.R", "bar.w", "bar.rho")   # bar.w at nonlocal-bond midpoints
#: open range (lower, upper) of a field's values: the physical range of its parameter
FIELD_RANGES = {"bar.E": (0.0, math.inf), "bar.R": (0.0, 1.0), "bar.rho": (0.0, math.inf),
                "bar.w": (0.0, math.inf)}
#: what each output is, in words (its ``long_name``; units are SI, "1" where dimensionless)
OUTPUT_LONG_NAMES = {
    "strain": "strain of the bar (end displacement / length)",
    "stress": "stress in the bar (end force / cross-section)",
    "failure_strain": "strain of the bar at failure",
    "failure_stress": "stress in the bar at failure",
    "sigma_stdev": "width of the nonlocal bond weights around each grid point",
    "x": "position of each grid point along the bar",
    "R": "modulus of softness of each local bond",
    "bond_strain": "strain of each local bond in the last state (at failure)",
    "mass": "mass of the bar",
    "stress_amplitude": "stress amplitude of each cyclic loop",
    "strain_amplitude": "strain amplitude of each cyclic loop",
    "plastic_strain_amplitude": "plastic strain amplitude of each cyclic loop",
    "n_prime": "cyclic strain hardening exponent n'",
    "K_prime": "cyclic strength coefficient K'",
    "broken": "whether the bar broke during the cycles (1) or survived them (0)",
    "break_cycle": "cycle in which the bar broke (cycles + 1: not within the cycles, it broke "
                   "in the pull after them)",
    "break_bond": "local bond whose strain first passed the failure strain",
    "break_position": "position of the midpoint of the bond that broke first",
}
#: cyclic outputs a bar broken during the cycles does not have: the path after the break,
#: the loops it did not finish, n' and K' fitted over every level (NaN in its run)
ABSENT_AFTER_BREAK = ("strain", "stress", "stress_amplitude", "strain_amplitude",
                      "plastic_strain_amplitude", "n_prime", "K_prime")
#: cyclic outputs that take discrete values: the outcome, the cycle, the bond and its place
DISCRETE_OUTPUTS = ("break_cycle", "break_bond", "break_position")
COORDINATE_LONG_NAMES = {"step": "load step", "point": "grid point", "bond": "local bond",
                         "loop": "cyclic loop (amplitude level)"}
DIAGNOSTIC_OUTPUTS = {"load_steps": "load steps the run followed (not counting the bisection "
                                    "of the failure load)",
                      "newton_iterations": "Newton iterations of those load steps",
                      "factorisations": "stiffness matrix factorisations of those load steps"}
RTOL = 1e-9           # Newton: |residual| ≤ RTOL · max(|F|, previous |F|, floor)
MAXIT = 100


# ------------------------------------------------------------------------------------------
# The solver
# ------------------------------------------------------------------------------------------

@register_solver("gamut_bar")
class GamutBarSolver(Solver):
    """1-D nonlocal deformation-gamut bar (seed 002): monotonic and cyclic tension–compression."""

    def __init__(self, cfg: dict, props: dict):
        self.cfg = cfg
        self.props = props                      # nominal material (scene), SI
        self.n = cfg["local_bonds"]
        self.weights = family_weights(cfg["sigma_stdev"], cfg["cutoff"])
        self.n_families = self.weights.size
        self._R_given = cfg.pop("R_given")
        if cfg["loading"] == "cyclic":
            amps = self._amplitudes(props)
            self.plan = CyclicPlan.for_amplitudes(amps, cfg["cycle_repeats"],
                                                  cfg["cyclic_increment"])
        else:
            self.plan = None
        self._nominal_x = uniform_grid(self.n, props["length"])
        self._template = self._make_template()

    # -- construction ----------------------------------------------------------------------

    @classmethod
    def from_scene(cls, scene: Mapping) -> "GamutBarSolver":
        cfg, props = parse_scene(scene)
        return cls(cfg, props)

    def _amplitudes(self, p):
        lo, hi = self.cfg["amplitude_range"]
        return np.geomspace(lo * p["sigma_y"], hi * p["sigma_y"], self.cfg["cycles"])

    @classmethod
    def report(cls, trees, folder, figures=True):
        """What gamut-bar results add to their report: the bar with its field realizations,
        and the comparisons with seed 002's Table 1 and figures (solvers/gamut_bar/report.py)."""
        return _report(trees, folder, figures, solver_class=cls)

    def describe(self) -> str:
        c = self.cfg
        return (f"gamut_bar/{c['material']} {c['loading']}, {self.n} local bonds, "
                f"{c['grid']} grid")

    # -- contract --------------------------------------------------------------------------

    def nominal(self) -> dict[str, float]:
        p = self.props
        return {"bar.E": p["E"], "bar.R": p["R"], "bar.w": 1.0, "bar.rho": p["rho"],
                "bar.sigma_y": p["sigma_y"], "bar.sigma_f": p["sigma_f"],
                "bar.eps_f": p["eps_f"], "bar.n_ro": p["n_ro"], "bar.K_ro": p["K_ro"],
                "bar.area": p["area"], "bar.length": p["length"]}

    def parameter_units(self) -> dict[str, str]:
        return dict(PARAMETER_UNITS)

    def field_points(self, name: str) -> np.ndarray:
        """Points (m) of the nominal (uniform) grid where a field is evaluated: local-bond
        midpoints for E, R, rho; the distinct nonlocal-bond midpoints for w."""
        key = _field_key(name)
        if key is None:
            return super().field_points(name)
        x = self._nominal_x
        if key == "bar.w":
            bonds = nonlocal_bonds(x, self._cut_length(self.props["length"]))
            idx = np.unique(bonds.midpoint_index)
            return (0.5 * (x[idx // 2] + x[(idx + 1) // 2]))[:, None]
        return (0.5 * (x[:-1] + x[1:]))[:, None]

    def field_range(self, name: str) -> tuple[float, float]:
        """The open range (lower, upper) a field's values must lie in."""
        return FIELD_RANGES[_field_key(name)]

    def outputs(self) -> xr.Dataset:
        return self._template.copy(deep=True)

    def _make_template(self) -> xr.Dataset:
        n = self.n
        nan = np.nan
        steps = self.cfg["curve_points"] if self.plan is None else self.plan.steps
        data = {
            "strain": (("step",), np.full(steps, nan), "1"),
            "stress": (("step",), np.full(steps, nan), "Pa"),
            "failure_strain": ((), nan, "1"),
            "failure_stress": ((), nan, "Pa"),
            "sigma_stdev": (("point",), np.full(n + 1, nan), "m"),
            "x": (("point",), np.full(n + 1, nan), "m"),
            "R": (("bond",), np.full(n, nan), "1"),
            "bond_strain": (("bond",), np.full(n, nan), "1"),
            "mass": ((), nan, "kg"),
        }
        coords = {"step": np.arange(steps), "point": np.arange(n + 1), "bond": np.arange(n)}
        if self.plan is not None:
            lv = self.plan.levels
            data.update({
                "stress_amplitude": (("loop",), np.full(lv, nan), "Pa"),
                "strain_amplitude": (("loop",), np.full(lv, nan), "1"),
                "plastic_strain_amplitude": (("loop",), np.full(lv, nan), "1"),
                "n_prime": ((), nan, "1"),
                "K_prime": ((), nan, "Pa"),
                "broken": ((), nan, "1"),
                "break_cycle": ((), nan, "1"),
                "break_bond": ((), nan, "1"),
                "break_position": ((), nan, "m"),
            })
            coords["loop"] = np.arange(lv)
        ds = xr.Dataset({k: xr.Variable(d, v, {UNITS: u, LONG_NAME: OUTPUT_LONG_NAMES[k]})
                         for k, (d, v, u) in data.items()}, coords=coords)
        if self.plan is not None:
            ds["broken"].attrs.update({FLAG_VALUES: np.array([0, 1], dtype=np.int8),
                                       FLAG_MEANINGS: "survived_the_cycles broken"})
            for name in DISCRETE_OUTPUTS:
                ds[name].attrs[OUTPUT_VALUES] = DISCRETE_VALUES
            ds["break_cycle"].attrs[NOT_WITHIN_LOADING] = float(self.plan.cycles + 1)
            for name in ABSENT_AFTER_BREAK:
                ds[name].attrs[UNDEFINED_WHEN] = "broken"
        for dim in coords:
            ds[dim].attrs[LONG_NAME] = COORDINATE_LONG_NAMES[dim]
        for name, long in DIAGNOSTIC_OUTPUTS.items():
            ds[name] = xr.Variable((), nan, {UNITS: "1", LONG_NAME: long,
                                             OUTPUT_KIND: DIAGNOSTIC_KIND})
        return ds

    # -- one realization -------------------------------------------------------------------

    def _cut_length(self, length):
        return self.cfg["cutoff"] * self.cfg["sigma_stdev"] * length / self.n

    def _properties(self, params):
        p = self.nominal()
        for name, value in params.items():
            if name not in p:
                raise SolverError(f"unknown parameter '{name}' (known: {', '.join(PARAMETERS)})")
            try:
                p[name] = float(value)
            except (TypeError, ValueError):
                raise SolverError(f"parameter '{name}' is not a number: {value!r}") from None
            if not math.isfinite(p[name]):
                raise SolverError(f"parameter '{name}' is not finite: {value!r}")
        q = {k.split(".", 1)[1]: v for k, v in p.items()}
        problem, R_cal = material_problem(q)
        if problem:
            raise SolverError(f"bar.{problem[0]}: {problem[1]}")
        if "bar.R" not in params and not self._R_given:
            q["R"] = R_cal          # eq. 18 of this run's properties
        if not 0.0 < q["R"] < 1.0:
            raise SolverError(f"bar.R = {q['R']!r} is not in (0, 1)")
        if not q["w"] > 0:
            raise SolverError(f"bar.w = {q['w']!r} is not > 0")
        return q, R_cal

    def _grid(self, length, seed):
        if self.cfg["grid"] == "uniform":
            return uniform_grid(self.n, length)
        rng = np.random.default_rng(self.cfg["grid_seed"] if seed is None else seed)
        return stochastic_grid(self.n, length, self.cfg["grid_factor"],
                               self.cfg["min_spacing_fraction"], rng)

    def run(self, params: Mapping[str, float] | None = None, fields=None,
            seed: int | None = None) -> xr.Dataset:
        q, R_cal = self._properties(dict(params or {}))
        _check_fields(fields)
        n, L, A = self.n, q["length"], q["area"]
        x = self._grid(L, seed)
        sbar = L / n
        sigma = self.cfg["sigma_stdev"] * sbar
        cut = self._cut_length(L)
        mid = 0.5 * (x[:-1] + x[1:])
        E_seg = _field_values(fields, "bar.E", mid, q["E"], "Pa")
        R_seg = _field_values(fields, "bar.R", mid, q["R"], "")
        rho = _field_values(fields, "bar.rho", mid, q["rho"], "kg/m3")
        bonds = nonlocal_bonds(x, cut)
        w_nominal = bond_weights(x, bonds, sigma, sbar, self.n_families)
        w = w_nominal
        if fields is not None and _field_key_in(fields, "bar.w") is not None:
            bmid = 0.5 * (x[bonds.p] + x[bonds.q])
            mu = _field_values(fields, "bar.w", bmid, q["w"], "", what="nonlocal bond")
            w = bond_weights(x, bonds, sigma, sbar, self.n_families, mu)
        cal = calibrate(q["E"], q["sigma_y"], q["n_ro"], q["K_ro"], q["eps_f"], R_cal,
                        self.weights)
        strains = np.geomspace(0.5 * q["sigma_y"] / q["E"], q["eps_f"], 60)
        corr = grid_correction(x, bonds, w_nominal, sbar, cal, q["R"], strains)
        net = build_network(x, E_seg, R_seg, A, bonds, w, cal, corr, E_ref=q["E"])
        sim = _Simulation(net, q["eps_f"], L, 1e-6 * q["sigma_y"] * A, float(E_seg.max()))

        ds = self._template.copy(deep=False)
        out = {"sigma_stdev": effective_sigma(n + 1, bonds, w, sigma), "x": x, "R": R_seg,
               "mass": float(np.sum(rho * A * net.seg))}
        if self.plan is None:
            out.update(self._monotonic(sim, q, A))
        else:
            out.update(self._cyclic(sim, q, A))
        out["bond_strain"] = np.diff(sim.u) / net.seg
        out.update(load_steps=sim.steps, newton_iterations=sim.iterations,
                   factorisations=sim.factorisations)
        reason = out.pop(NO_VALUE_REASON, None)
        for name, value in out.items():
            var = ds.variables[name]
            var.values = np.asarray(value, dtype=float).reshape(var.shape).copy()
        ds.attrs.update(sim.summary())
        if reason:
            ds.attrs[NO_VALUE_REASON] = reason
        return ds

    def _monotonic(self, sim, q, A):
        c = self.cfg
        f_cap = 10.0 * sim.E_max * q["eps_f"] * A   # the network's stress is below E·ε
        forces = monotonic_forces(c["initial_force"], c["force_growth"], f_cap)
        done = sim.follow(forces)
        if done == forces.size:
            raise SolverError(f"no failure up to {forces[-1]:.4g} N "
                              f"(stress {forces[-1] / A:.4g} Pa)")
        if done == 0:
            raise SolverError(f"step 0 (force {forces[0]:.4g} N) failed: {sim.failure_text()}")
        f_lo = sim.bisect(forces[done - 1], forces[done], c["bisections"])
        strain = np.concatenate([[0.0], sim.out_u[:done] / sim.L, [sim.u[-1] / sim.L]])
        stress = np.concatenate([[0.0], forces[:done] / A, [f_lo / A]])
        es, ss = resample_path(strain, stress, q["eps_f"], q["sigma_f"], c["curve_points"])
        return {"strain": es, "stress": ss, "failure_strain": sim.u[-1] / sim.L,
                "failure_stress": f_lo / A}

    def _cyclic(self, sim, q, A):
        c = self.cfg
        plan = self.plan
        peaks = self._amplitudes(q) * A
        forces, starts = plan.forces(peaks)
        done = sim.follow(forces[1:])
        if done < forces.size - 1:
            s = done + 1
            where = (f"cyclic step {s} (force {forces[s]:.6g} N, stress {forces[s] / A:.6g} "
                     f"Pa)")
            if sim.failure[0] != K.STRAIN:
                # a step Newton cannot carry is the solver's failure, not the bar's: the
                # hardening share h E never slips, so the bar has no limit load in the cycles
                raise SolverError(f"{where} failed: {sim.failure_text()}")
            return self._broken_in_cycles(sim, q, A, forces, starts, s, where)
        strain = np.concatenate([[0.0], sim.out_u[:done] / sim.L])
        stress = forces / A
        sig_a, eps_a, eps_pa = loop_amplitudes(strain, stress, starts, 2 * plan.per_half,
                                               q["E"])
        n_prime, K_prime, used = fit_cyclic(sig_a, eps_pa, eps_a)
        if used < 2:
            raise SolverError(f"only {used} loop(s) with a plastic strain amplitude: n' and K' "
                              f"cannot be fitted")
        # pull to failure from the last peak (Masing memory: back on the virgin curve)
        f_cap = 10.0 * sim.E_max * q["eps_f"] * A
        pull = peaks[-1] * monotonic_forces(c["force_growth"], c["force_growth"],
                                            f_cap / peaks[-1])
        done2 = sim.follow(pull)
        f_prev = peaks[-1] if done2 == 0 else pull[done2 - 1]
        if done2 == pull.size:
            raise SolverError(f"no failure up to {pull[-1]:.4g} N after the cycles")
        f_lo = sim.bisect(f_prev, pull[done2], c["bisections"])
        bond = sim.breaking_bond()
        return {"strain": strain, "stress": stress, "stress_amplitude": sig_a,
                "strain_amplitude": eps_a, "plastic_strain_amplitude": eps_pa,
                "n_prime": n_prime, "K_prime": K_prime, "failure_strain": sim.u[-1] / sim.L,
                "failure_stress": f_lo / A, "broken": 0.0,
                "break_cycle": float(plan.cycles + 1), "break_bond": float(bond),
                "break_position": sim.bond_midpoint(bond)}

    def _broken_in_cycles(self, sim, q, A, forces, starts, s, where):
        """A bar whose bond passed eps_f in cyclic step ``s``: an outcome. The force at the
        break is bisected as after the pull; the path stops there (NaN after it), the loops
        finished before it keep their amplitudes, and n', K' (a fit over every level) have no
        value. The reason goes with the run (``NO_VALUE_REASON``) for a study storing them."""
        plan = self.plan
        text = sim.failure_text()
        bond = sim.failure[1]
        f_lo = sim.bisect(forces[s - 1], forces[s], self.cfg["bisections"])
        strain = np.full(plan.steps, np.nan)
        stress = np.full(plan.steps, np.nan)
        strain[:s] = np.concatenate([[0.0], sim.out_u[:s - 1] / sim.L])
        stress[:s] = forces[:s] / A
        span = 2 * plan.per_half
        amplitudes = [np.full(plan.levels, np.nan) for _ in range(3)]
        finished = starts[:, -1] + span < s      # the level's last loop ended before step s
        if finished.any():
            found = loop_amplitudes(strain, stress, starts[finished], span, q["E"])
            for whole, part in zip(amplitudes, found):
                whole[finished] = part
        cycle = plan.cycle_of_step(s)
        return {"strain": strain, "stress": stress, "stress_amplitude": amplitudes[0],
                "strain_amplitude": amplitudes[1], "plastic_strain_amplitude": amplitudes[2],
                "failure_strain": sim.u[-1] / sim.L, "failure_stress": f_lo / A,
                "broken": 1.0, "break_cycle": float(cycle), "break_bond": float(bond),
                "break_position": sim.bond_midpoint(bond),
                NO_VALUE_REASON: f"the bar broke in cycle {cycle} of {plan.cycles}, {where}: "
                                 f"{text}"}


# ------------------------------------------------------------------------------------------
# Fields
# ------------------------------------------------------------------------------------------

def _field_key(name):
    if name in FIELDS:
        return name
    if isinstance(name, str) and f"bar.{name}" in FIELDS:
        return f"bar.{name}"
    return None


def _field_key_in(fields, name):
    """The key under which ``fields`` holds parameter ``name`` ("bar.E" or "E"), or None."""
    for key in (name, name.split(".", 1)[1]):
        try:
            if key in fields:
                return key
        except TypeError:
            return None
    return None


def _check_fields(fields):
    if fields is None:
        return
    try:
        keys = list(fields.keys()) if hasattr(fields, "keys") else list(fields)
    except TypeError:
        return
    for key in keys:
        if _field_key(key) is None:
            raise SolverError(f"no random field '{key}' in gamut_bar (fields: "
                              f"{', '.join(FIELDS)})")


def _field_values(fields, name, points, mean, unit, what="local bond"):
    """The realization's field ``name`` at ``points`` (or the scalar ``mean`` everywhere);
    SolverError if a value is outside its range (``FIELD_RANGES``) or not finite."""
    lower, upper = FIELD_RANGES[name]
    key = _field_key_in(fields, name) if fields is not None else None
    if key is None:
        vals = np.full(points.size, float(mean))
    else:
        vals = np.asarray(fields.values(key, points, mean, lower, upper), dtype=float)
        vals = vals.reshape(-1)
        if vals.size != points.size:
            raise SolverError(f"field {name} returned {vals.size} values for {points.size} "
                              f"points")
    ok = np.isfinite(vals) & (vals > lower) & (vals < upper)
    if not ok.all():
        i = int(np.flatnonzero(~ok)[0])
        bound = f"in ({lower:g}, {upper:g})" if math.isfinite(upper) else f"> {lower:g}"
        raise SolverError(f"{name} is not {bound} at {what} {i} (x = {points[i]:.6g} m): "
                          f"{vals[i]!r} {unit}".rstrip())
    return vals


# ------------------------------------------------------------------------------------------
# State and driver calls
# ------------------------------------------------------------------------------------------

class _Simulation:
    """The state of one bar (displacements, slips, factor) and the kernel calls on it."""

    def __init__(self, net, eps_f, L, f_floor, E_max):
        self.net = net
        self.eps_f = float(eps_f)
        self.L = float(L)
        self.f_floor = float(f_floor)
        self.E_max = E_max
        self.last_force = 0.0
        nn = net.x.size - 1
        ne = net.k.size
        b = max(net.bandwidth, 1)
        self.u = np.zeros(nn + 1)
        self.ep_n = np.zeros(ne)
        self.ep = np.zeros(ne)
        self.st = np.zeros(ne, dtype=np.int8)
        self.ab = np.zeros((nn, b + 1))
        self.diag = np.zeros(nn)
        self.fst = np.zeros(ne, dtype=np.int8)
        self.fmeta = np.zeros(3, dtype=np.int64)
        self.fmeta_f = np.zeros(1)
        self.work = (np.zeros(nn), np.zeros(nn), np.zeros(ne), np.zeros(ne, dtype=np.int8),
                     np.zeros(nn), np.zeros(nn + 1), np.zeros(nn + 1))
        self.umax = 100.0 * max(self.eps_f, 1.0) * self.L
        self.info = np.zeros(5)
        self.out_u = np.zeros(0)
        self.iterations = 0
        self.factorisations = 0
        self.steps = 0
        self.failure = None

    def _tols(self, forces, previous):
        prev = np.concatenate([[previous], forces[:-1]])
        return RTOL * np.maximum(np.maximum(np.abs(forces), np.abs(prev)), self.f_floor)

    def follow(self, forces):
        """Follow the forces from the current state up to the first failing step; returns the
        number of steps done (the state is that of the last one)."""
        n = self.net
        forces = np.ascontiguousarray(forces, dtype=float)
        prev = self.last_force
        out = np.zeros(forces.size)
        wr, wdu, wep, wst, wr2, uold, uprev = self.work
        done = K.run_path(forces, self._tols(forces, prev), self.u, self.ep_n, self.ep,
                          self.st, n.ei, n.ej, n.k, n.fc, self.ab, self.diag, self.fst,
                          self.fmeta, self.fmeta_f, wr, wdu, wep, wst, wr2, uold, uprev, n.seg,
                          self.eps_f, out, MAXIT, self.umax, self.info)
        self.out_u = out
        self.steps += done
        self.iterations += int(self.info[3])
        self.factorisations += int(self.info[4])
        status = int(self.info[0])
        if done:
            self.last_force = float(forces[done - 1])
        if status != K.OK:
            self.failure = (status, int(self.info[1]), float(self.info[2]))
        return done

    def bisect(self, f_lo, f_hi, nbis):
        n = self.net
        wr, wdu, wep, wst, wr2, uold, uprev = self.work
        f = K.bisect_failure(float(f_lo), float(f_hi), nbis, RTOL, self.f_floor, self.u,
                             self.ep_n, self.ep, self.st, n.ei, n.ej, n.k, n.fc, self.ab,
                             self.diag, self.fst, self.fmeta, self.fmeta_f, wr, wdu, wep, wst,
                             wr2, uold, uprev, n.seg, self.eps_f, MAXIT, self.umax)
        self.last_force = float(f)
        return float(f)

    def failure_text(self):
        if self.failure is None:
            return "no failure"
        status, where, value = self.failure
        text = K.STATUS_TEXT.get(status, f"status {status}")
        x = self.net.x
        if status == K.STRAIN:
            text += (f" (bond {where}, x = {0.5 * (x[where] + x[where + 1]):.6g} m, strain "
                     f"{value:.6g} > {self.eps_f:g})")
        elif 0 <= where < x.size:
            text += f" (point {where}, x = {x[where]:.6g} m"
            text += ")" if not math.isfinite(value) else f", residual force {value:.6g} N)"
        return text

    def breaking_bond(self):
        """The bond that broke: the one past eps_f, or at a limit load the most strained."""
        if self.failure is not None and self.failure[0] == K.STRAIN:
            return int(self.failure[1])
        return int(np.argmax(np.abs(np.diff(self.u)) / self.net.seg))

    def bond_midpoint(self, bond):
        return 0.5 * float(self.net.x[bond] + self.net.x[bond + 1])

    def summary(self):
        mode = "none"
        if self.failure is not None:
            mode = "local strain" if self.failure[0] == K.STRAIN else "limit load"
        return {"failure_mode": mode, "steps": self.steps, "newton_iterations": self.iterations,
                "factorisations": self.factorisations, "elements": int(self.net.k.size),
                "bandwidth": int(self.net.bandwidth)}
