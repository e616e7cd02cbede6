"""Explicit 2-D plane-strain material point method (MUSL) as a uqflow Solver (seed 000;
docs/mpm.md). Kernels: ``step.py``; scene: ``scene.py``; materials: ``materials/``."""

from __future__ import annotations

import math
import time as _time
from collections.abc import Mapping

import numba
import numpy as np
import xarray as xr

from solvers.mpm import step as K
from solvers.mpm.kernel_cache import is_cached
from solvers.mpm.materials import state as ST
from solvers.mpm.materials.johnson_cook import CONVENTIONS_PARAMETER
from solvers.mpm.materials.parameters import units as parameter_units
from solvers.mpm.probe_sensitivities import OUTPUTS as SENSITIVITY_OUTPUTS, \
    ProbeSensitivities, sensitivity_parameters
from solvers.mpm.probes import LABELS as OUTPUT_LABELS, ProbeRecorder
from solvers.mpm.snapshots import SnapshotWriter
from solvers.mpm.scene import ENERGY_OUTPUTS, PROBE_QUANTITIES, apply_conventions, \
    auto_extent, parse, place_probes, probe_members, seed_particles
from solvers.mpm.shapes import KINDS
from uqflow.errors import SceneError, SolverError
from uqflow.solver import DIAGNOSTIC_KIND, Solver, register_solver

CORE_SET = ("det_x", "det_y", "burn_width")   # explosive parameters the core sets from the scene
BURN_WIDTH_CELLS = 1.5                         # programmed-burn ramp width, cells (β of jwl.py)
SERIAL_BELOW = 20_000    # particles: below this, one thread (a parallel launch costs more)
DT_FLOOR_FRACTION = 1e-3                       # default dt floor: this × the first step's dt
DIAGNOSTIC_OUTPUTS = {"time_steps": ("1", "time steps taken (the run's cost)"),
                      "dt_min": ("s", "smallest time step"),
                      "dt_max": ("s", "largest time step")}


@register_solver("mpm")
class MPMSolver(Solver):
    """Explicit 2-D plane-strain MPM (MUSL, quadratic B-splines) with EOS/strength materials."""

    @staticmethod
    def report(trees, folder, figures=True, time=None, reference=None):
        """``uqflow report`` on MPM results: seed 000's Tables 6-8 and 3/9, Figs. 5-6, 9-12
        (solvers/mpm/report.py, docs/mpm_report.md); imported when called, so a worker
        that only runs the solver never loads the report's tables and plotting."""
        from solvers.mpm.report import report
        return report(trees, folder, figures=figures, time=time, reference=reference)

    def __init__(self, cfg):
        self.extent_info = {}
        if cfg.extent == "auto":
            cfg = self._crop(cfg)
        _apply_conventions(cfg)
        self.cfg = cfg
        self.parts = seed_particles(cfg)
        if self.parts.x.size == 0:
            raise SceneError("no particle: no body covers a lattice point", key="scene.bodies")
        for k, b in enumerate(cfg.bodies):
            if not np.any(self.parts.body == k):
                raise SceneError(f"body {b.name!r} has no particle (smaller than the particle "
                                 f"spacing, or covered by earlier bodies)",
                                 key=f"scene.bodies[{k}]")
        self.probe_index = place_probes(cfg, self.parts)
        self.probe_members = probe_members(cfg, self.parts, self.probe_index)
        self.labels = list(cfg.materials)
        explosive = [lab for lab, m in cfg.materials.items() if "det_x" in m.module.PARAMETERS]
        if explosive and cfg.detonation is None:
            raise SceneError(f"material {explosive[0]!r} is an explosive: give the detonation "
                             f"point", key="scene.detonation")
        self.mat_index = [np.flatnonzero(self.parts.material == k).astype(np.int64)
                          for k in range(len(self.labels))]
        self.modules = [cfg.materials[lab].module for lab in self.labels]
        self.fixx, self.fixy = cfg.grid.masks()
        self.times = cfg.times
        self._template = self._make_template()

    def _crop(self, cfg):
        """extent = "auto": crop the domain to the probes' domain of dependence
        (``scene.auto_extent``), with the wave speeds of the nominal materials."""
        if not cfg.probes:
            raise SceneError("extent = \"auto\" needs at least one probe", key="scene.extent")
        parts = seed_particles(cfg)
        probe_index = place_probes(cfg, parts)
        speeds = []
        for lab, m in cfg.materials.items():
            vals = dict(m.values)
            if "det_x" in m.module.PARAMETERS and cfg.detonation is not None:
                vals["det_x"], vals["det_y"] = cfg.detonation
            try:
                prm = m.module.pack(vals)
            except SolverError as exc:
                raise SceneError(str(exc), key=f"scene.materials.{lab}") from None
            row = ST.new_state(1)
            m.module.init(prm, row, 0)
            speeds.append(float(row[0, ST.C]))
        new, info = auto_extent(cfg, parts, speeds, probe_index)
        self.extent_info = info
        return new

    @classmethod
    def from_scene(cls, scene: Mapping) -> "MPMSolver":
        return cls(parse(scene))

    def describe(self) -> str:
        g = self.cfg.grid
        mats = ", ".join(f"{lab} ({m.model})" for lab, m in self.cfg.materials.items())
        text = (f"mpm: {g.ncx}x{g.ncy} cells of {g.dx:g} m, {self.parts.x.size} particles, "
                f"{self.cfg.shape} shape functions; materials {mats}")
        if self.extent_info:
            e = self.extent_info
            text += (f"; extent auto: [{e['extent'][0]:g}, {e['extent'][1]:g}] x "
                     f"[{e['extent'][2]:g}, {e['extent'][3]:g}] m, {e['cells_saved']} of "
                     f"{e['full_cells']} cells saved")
        return text

    # -- contract --------------------------------------------------------------------------
    def nominal(self) -> dict[str, float]:
        """``<material label>.<parameter>`` for every parameter of every material in use
        (the explosive's detonation point and burn width, and the steel's
        ``seed_conventions`` flag, are set from the scene, not listed)."""
        out = {}
        for lab, m in self.cfg.materials.items():
            for name, v in m.values.items():
                if name in CORE_SET and "det_x" in m.module.PARAMETERS:
                    continue
                if name == CONVENTIONS_PARAMETER:     # the scene's `conventions`, not sampled
                    continue
                out[f"{lab}.{name}"] = float(v)
        return out

    def parameter_units(self) -> dict[str, str]:
        """SI units of every nominal parameter, from its material's spec table."""
        units = {lab: parameter_units(m.module.PARAMETER_SPECS)
                 for lab, m in self.cfg.materials.items()}
        return {k: units[lab][name]
                for k in self.nominal() for lab, name in [k.split(".", 1)]}

    def outputs(self) -> xr.Dataset:
        return self._template.copy(deep=True)

    def _make_template(self) -> xr.Dataset:
        nt, npr = self.times.size, len(self.cfg.probes)
        data = {}
        for name in self.cfg.outputs:
            units, description = PROBE_QUANTITIES[name]
            data[name] = xr.Variable(("time", "probe"), np.full((nt, npr), np.nan),
                                     {"units": units, "long_name": OUTPUT_LABELS[name],
                                      "description": description})
        for name, units in ENERGY_OUTPUTS.items():
            data[name] = xr.Variable(("time",), np.full(nt, np.nan),
                                     {"units": units, "long_name": OUTPUT_LABELS[name]})
        for name, (units, long) in DIAGNOSTIC_OUTPUTS.items():
            data[name] = xr.Variable((), np.nan, {"units": units, "long_name": long,
                                                  "output_kind": DIAGNOSTIC_KIND})
        points = np.array([p.point for p in self.cfg.probes], dtype=float).reshape(npr, 2)
        coords = {"time": xr.Variable(("time",), self.times, {"units": "s",
                                                             "long_name": "time"}),
                  "probe": [p.name for p in self.cfg.probes],
                  "probe_x": xr.Variable(("probe",), points[:, 0], {"units": "m",
                                                                    "long_name": "x"}),
                  "probe_y": xr.Variable(("probe",), points[:, 1], {"units": "m",
                                                                    "long_name": "y"})}
        return xr.Dataset(data, coords=coords)

    # -- one realization -------------------------------------------------------------------
    def _parameters(self, params):
        nominal = self.nominal()
        values = {lab: dict(m.values) for lab, m in self.cfg.materials.items()}
        for name, v in params.items():
            if name not in nominal:
                raise SolverError(f"unknown parameter '{name}' (known: "
                                  f"{', '.join(sorted(nominal))})")
            try:
                v = float(v)
            except (TypeError, ValueError):
                raise SolverError(f"parameter '{name}' is not a number: {v!r}") from None
            if not math.isfinite(v):
                raise SolverError(f"parameter '{name}' is not finite: {v!r}")
            lab, pname = name.split(".", 1)
            values[lab][pname] = v
        prms = []
        for lab in self.labels:
            m = self.cfg.materials[lab]
            vals = values[lab]
            if "det_x" in m.module.PARAMETERS:
                vals["det_x"], vals["det_y"] = self.cfg.detonation
                if "burn_width" not in m.overrides:
                    vals["burn_width"] = BURN_WIDTH_CELLS * self.cfg.grid.dx
            try:
                prms.append(np.ascontiguousarray(m.module.pack(vals), dtype=np.float64))
            except SceneError as exc:          # a value the material refuses
                raise SolverError(f"material '{lab}': {exc.reason}") from None
            except SolverError as exc:
                raise SolverError(f"material '{lab}' ({m.model}): {exc}") from None
        return prms

    def run(self, params: Mapping[str, float] | None = None,
            fields: Mapping[str, np.ndarray] | None = None) -> xr.Dataset:
        if fields:
            raise SolverError(f"the mpm solver takes no random fields (got "
                              f"{', '.join(map(str, fields))})")
        return self._execute(params)

    def local_sensitivities(self) -> dict[str, tuple[str, ...]]:
        """The scene's outputs with local (frozen-state) derivatives — ``pressure``,
        ``flow_stress``, ``flow_stress_total_rate``, ``S11``, ``S22``, ``S12``, ``S33`` — each
        with the EOS (S1, S2, S3, γ0, a) and Johnson–Cook (A, B, C, n, m) parameters of every
        MG–JC steel in the scene (``probe_sensitivities.py``: which of these vanish and why).
        Empty when the scene has no such steel."""
        wrt = sensitivity_parameters(self)
        if not wrt:
            return {}
        return {o: wrt for o in self.cfg.outputs if o in SENSITIVITY_OUTPUTS}

    def run_with_sensitivities(self, params, wrt, outputs) -> xr.Dataset:
        """``run(params)`` plus ``<o>__gradient`` (time, probe, parameter) and ``<o>__hessian``
        (time, probe, parameter, parameter_j) for each ``o`` in ``outputs``: derivatives at
        the realization's parameters with the state of each output time held fixed
        (probe_sensitivities.py); the recording runs at output times only."""
        wrt, outputs = [str(w) for w in wrt], [str(o) for o in outputs]
        available = self.local_sensitivities()
        for o in outputs:
            if o not in available:
                raise SolverError(f"output '{o}' has no local derivative in this scene (with "
                                  f"derivatives: {', '.join(available) or 'none'}); use "
                                  f"method 'taylor'")
            missing = [w for w in wrt if w not in available[o]]
            if missing:
                raise SolverError(f"output '{o}' has no local derivative with respect to "
                                  f"'{missing[0]}' (only {', '.join(available[o])}); use "
                                  f"method 'taylor'")
        if len(set(wrt)) != len(wrt):
            raise SolverError(f"parameters listed twice in wrt: {wrt}")
        return self._execute(params, wrt, outputs)

    def compile_shares(self) -> int:
        """0 when every kernel a run of this scene calls is in numba's on-disk cache for this
        CPU, else the number of shares ``warm_up`` splits their compilation into: the grid
        kernels, and each material's loops."""
        parallel = run_threads(self.cfg, self.parts.x.size) > 1
        kernels = K.kernels(parallel)
        # what every run calls (check_state runs only after a failure: it may never compile)
        grid = (kernels.p2g, kernels.grid_solve, kernels.g2p_velocity_remap,
                kernels.g2p_gradient, kernels.max_speed, kernels.energies)
        loops = [f for module in self.modules for f in K.loop_for(module, parallel)]
        if all(is_cached(f) for f in (*grid, *loops)):
            return 0
        return 1 + len(self.modules)

    def warm_up(self, part: int = 0, parts: int = 1) -> None:
        """Compile (or load from numba's cache) share ``part`` of ``parts`` of the kernels a
        run of this scene calls, by calling them on a fresh run at the nominal parameters:
        share 0 holds the grid kernels, the materials' loops are dealt to shares 1, 2, ...
        (to share 0 as well when ``parts`` is 1). Processes sharing the cache folder, each
        warming its own share side by side, then load the others' code instead of
        compiling it (``uqflow.warm_up``)."""
        run = _Run(self, self._parameters({}))
        speed = float(np.max(run.S[:, ST.C] + np.hypot(run.vx, run.vy)))
        dt = self.cfg.cfl * self.cfg.grid.dx / speed if speed > 0.0 else self.cfg.end_time
        if part == 0:
            run.recorder.record(0, run)
            run.max_speed()
            run._grid_phase(dt, _no_lap)
        others = max(parts - 1, 1)
        mine = [k for k in range(len(run.loops)) if parts == 1 or 1 + k % others == part]
        run._material_phase(dt, _no_lap, mine)

    def _execute(self, params, wrt=None, outputs=()):
        prms = self._parameters(dict(params or {}))
        run = _Run(self, prms)
        if outputs:
            run.sensitivities = ProbeSensitivities(self, prms, run.recorder.members, wrt,
                                                   outputs, self.times.size)
        run.snapshots = SnapshotWriter.open(self.cfg, params)   # None without scene.snapshots
        try:
            run.advance()
        finally:
            if run.snapshots is not None:
                run.snapshots.close()
        ds = self._template.copy(deep=True)
        for name, arr in run.recorder.results().items():
            ds[name].values[...] = arr
        ds["time_steps"].values[...] = run.step_no
        ds["dt_min"].values[...] = run.dt_used_min
        ds["dt_max"].values[...] = run.dt_used_max
        if outputs:
            ds = ds.assign_coords(parameter=("parameter", wrt), parameter_j=("parameter_j", wrt))
            sens = run.sensitivities
            for o in outputs:
                dims = ds[o].dims
                ds[o + "__gradient"] = ((*dims, "parameter"), sens.gradient[o])
                ds[o + "__hessian"] = ((*dims, "parameter", "parameter_j"), sens.hessian[o])
        ds.attrs.update(run.summary())
        if self.extent_info:
            ds.attrs.update({k: v for k, v in self.extent_info.items() if k != "extent"})
            ds.attrs["extent"] = np.array(self.extent_info["extent"])
        return ds


def _apply_conventions(cfg):
    """The scene's ``conventions`` on the materials (``scene.apply_conventions``; parse has
    applied them already, a Config built otherwise gets them here)."""
    cfg.materials = apply_conventions(cfg.materials, getattr(cfg, "conventions", "uqflow"))


# ------------------------------------------------------------------------------------------

def _no_lap(name):
    pass


def run_threads(cfg, n):
    """numba threads of a run of ``n`` particles: the scene's ``threads``, or (0) all of
    them from SERIAL_BELOW particles on."""
    avail = numba.config.NUMBA_NUM_THREADS
    if cfg.threads:
        return min(cfg.threads, avail)
    return 1 if n < SERIAL_BELOW else min(numba.get_num_threads(), avail)


class _Run:
    """The arrays of one realization and the time loop."""

    def __init__(self, solver: MPMSolver, prms):
        cfg = solver.cfg
        self.solver = solver
        self.cfg = cfg
        self.prms = prms
        p = solver.parts
        n = p.x.size
        self.x = p.x.copy()
        self.y = p.y.copy()
        self.vx = p.vx.copy()
        self.vy = p.vy.copy()
        self.xn = np.empty(n)
        self.yn = np.empty(n)
        self.vol0 = p.vol0
        rho0 = np.array([pr[list(cfg.materials[lab].module.PARAMETERS).index("rho0")]
                         for lab, pr in zip(solver.labels, prms)])
        self.mass = rho0[p.material] * p.vol0
        self.S = ST.new_state(n)
        self.Lg = np.zeros((n, 4))
        self.err = np.zeros(n, dtype=np.int64)
        g = cfg.grid
        self.g = g
        shp = (g.nnx, g.nny)
        self.gm, self.gpx, self.gpy, self.gfx, self.gfy = (np.zeros(shp) for _ in range(5))
        self.gvx, self.gvy, self.gdx, self.gdy = (np.zeros(shp) for _ in range(4))
        self.nthreads = run_threads(cfg, n)
        self.buf = K.grid_buffers(self.nthreads, g.nnx, g.nny)
        self.kernels = K.kernels(parallel=self.nthreads > 1)
        self.loops = [K.loop_for(module, parallel=self.nthreads > 1)
                      for module in solver.modules]
        self.fixx, self.fixy = solver.fixx, solver.fixy
        self.kind = KINDS[cfg.shape]
        self.lp = 0.5 / cfg.ppc
        self.inv_dx = 1.0 / g.dx
        self.sides = g.folded_side_codes()
        self.etax, self.etay = g.dashpots(self._impedances())
        self.bnodes = g.boundary_nodes()
        self.mtiny = 1e-12 * float(self.mass.min())
        self.t = 0.0
        self.step_no = 0
        self.dt_used_min = math.inf
        self.dt_used_max = 0.0
        self.wall = 0.0
        self.vmax = None          # max (c + |v|) for the next CFL step, set by ``_step``
        for k, (_update, ini) in enumerate(self.loops):
            if ini(prms[k], self.S, solver.mat_index[k], self.err):
                self._raise_first("initial state")
        self.recorder = ProbeRecorder(cfg, solver.probe_members, solver.times.size)
        self.snapshots = None     # a snapshots.SnapshotWriter, set by MPMSolver.run
        self.sensitivities = None  # a ProbeSensitivities, set by run_with_sensitivities

    def _impedances(self):
        """{side: (ρ0 c_p, ρ0 c_s)} of each absorbing side: the material of the particle
        nearest to the side's boundary line at t = 0, at its reference state (c_p: the wave
        speed its ``init`` sets; c_s = √(G/ρ0), 0 for a fluid)."""
        g, sol = self.g, self.solver
        out = {}
        for side, kind in g.sides.items():
            if kind != "absorbing":
                continue
            dist = {"left": self.x - g.x0, "right": g.x1 - self.x, "bottom": self.y - g.y0,
                    "top": g.y1 - self.y}[side]
            k = int(sol.parts.material[int(np.argmin(np.abs(dist)))])
            module, prm = self.cfg.materials[sol.labels[k]].module, self.prms[k]
            names = list(module.PARAMETERS)
            rho0 = float(prm[names.index("rho0")])
            row = ST.new_state(1)
            module.init(prm, row, 0)
            if "shear_modulus" in names:
                G = float(prm[names.index("shear_modulus")])
            elif "E" in names and "nu" in names:
                G = float(prm[names.index("E")]) / (2.0 * (1.0 + float(prm[names.index("nu")])))
            else:
                G = 0.0
            out[side] = (rho0 * float(row[0, ST.C]), math.sqrt(rho0 * G))
        return out

    # -- errors ----------------------------------------------------------------------------
    def _describe(self, i):
        sol = self.solver
        b = self.cfg.bodies[int(sol.parts.body[i])]
        lab = sol.labels[int(sol.parts.material[i])]
        return (f"particle {i} (body '{b.name}', material '{lab}' "
                f"[{self.cfg.materials[lab].model}], x = {self.x[i]:.6g} m, "
                f"y = {self.y[i]:.6g} m)")

    def _raise_first(self, what):
        bad = np.flatnonzero(self.err)
        if bad.size == 0:
            raise SolverError(f"step {self.step_no} (t = {self.t:.6g} s, {what}): a kernel "
                              f"flagged a particle but recorded no code")
        i = int(bad[0])
        code = int(self.err[i])
        where = f"step {self.step_no} (t = {self.t:.6g} s, {what})"
        if code in K.CORE_ERROR_TEXT:
            text = K.CORE_ERROR_TEXT[code]
            if code == K.ERR_LEFT_GRID:
                g = self.g
                value = (f"position ({self.x[i]:.6g}, {self.y[i]:.6g}) m, velocity "
                         f"({self.vx[i]:.6g}, {self.vy[i]:.6g}) m/s; padded grid "
                         f"[{g.ox:.6g}, {g.ox + (g.nnx - 1) * g.dx:.6g}] x "
                         f"[{g.oy:.6g}, {g.oy + (g.nny - 1) * g.dx:.6g}] m")
            else:
                value = (f"velocity ({self.vx[i]:.6g}, {self.vy[i]:.6g}) m/s, "
                         f"state row {np.array2string(self.S[i], precision=4)}")
        else:
            text = ST.error_text(code)
            r = self.S[i]
            lab = self.solver.labels[int(self.solver.parts.material[i])]
            rho0 = self.cfg.materials[lab].values.get("rho0", math.nan)
            value = (f"before the step rho = {r[ST.RHO]:.6g} kg/m3 (J = {rho0 / r[ST.RHO]:.6g}"
                     f", mu = {r[ST.RHO] / rho0 - 1:.6g}), p = {r[ST.P]:.6g} Pa, "
                     f"q = {r[ST.Q]:.6g} Pa, E = {r[ST.E]:.6g} J/m3; velocity gradient "
                     f"{np.array2string(self.Lg[i], precision=4)} 1/s")
        more = f" ({bad.size - 1} more particle(s) flagged)" if bad.size > 1 else ""
        raise SolverError(f"{where}: {self._describe(i)}: {text} [code {code}]: "
                          f"{value}{more}")

    # -- time loop -------------------------------------------------------------------------
    def advance(self):
        before = numba.get_num_threads()
        numba.set_num_threads(self.nthreads)
        try:
            self._advance()
        finally:
            numba.set_num_threads(before)

    def _advance(self):
        cfg = self.cfg
        t0 = _time.perf_counter()
        times = self.solver.times
        self.recorder.record(0, self)
        if self.sensitivities is not None:
            self.sensitivities.record(0, self)
        if self.snapshots is not None:
            self.snapshots.maybe_write(0, self)
        dt_floor = cfg.dt_min
        for k in range(1, times.size):
            target = times[k]
            while True:
                rem = target - self.t
                if rem <= 1e-12 * target:
                    break
                vmax = self.max_speed()
                if not math.isfinite(vmax):
                    self.err[:] = 0
                    self.kernels.check_state(self.S, self.err)
                    self.err[~(np.isfinite(self.vx) & np.isfinite(self.vy))] = \
                        K.ERR_CORE_NONFINITE
                    if not self.err.any():
                        raise SolverError(f"step {self.step_no} (t = {self.t:.6g} s): "
                                          f"non-finite wave speed + velocity {vmax!r}")
                    self._raise_first("time step")
                dt_cfl = cfg.cfl * self.g.dx / vmax if vmax > 0 else rem
                if dt_floor is None:
                    dt_floor = DT_FLOOR_FRACTION * dt_cfl
                if dt_cfl < dt_floor:
                    sp = self.S[:, ST.C] + np.hypot(self.vx, self.vy)
                    i = int(np.argmax(sp))
                    raise SolverError(
                        f"step {self.step_no} (t = {self.t:.6g} s): time step {dt_cfl:.4g} s "
                        f"below the floor {dt_floor:.4g} s: {self._describe(i)} has "
                        f"c + |v| = {sp[i]:.6g} m/s (c = {self.S[i, ST.C]:.6g} m/s)")
                if rem <= dt_cfl:
                    dt = rem
                elif rem < 2.0 * dt_cfl:
                    dt = 0.5 * rem
                else:
                    dt = dt_cfl
                self._step(dt)
                self.t = target if dt == rem else self.t + dt
                self.step_no += 1
                self.dt_used_min = min(self.dt_used_min, dt)
                self.dt_used_max = max(self.dt_used_max, dt)
                if self.step_no >= cfg.max_steps:
                    raise SolverError(f"step {self.step_no} (t = {self.t:.6g} s): max_steps "
                                      f"= {cfg.max_steps} reached before end_time "
                                      f"{cfg.end_time:g} s")
            self.recorder.record(k, self)
            if self.sensitivities is not None:
                self.sensitivities.record(k, self)
            if self.snapshots is not None:
                self.snapshots.maybe_write(k, self)
        self.wall = _time.perf_counter() - t0

    def _step(self, dt, lap=None):
        """One MUSL step (step.py). ``lap(name)``, when given, is called after each kernel
        with the kernel's name (the benchmark's per-kernel profile)."""
        lap = lap or _no_lap
        self._grid_phase(dt, lap)
        self._material_phase(dt, lap, range(len(self.loops)))

    def _grid_phase(self, dt, lap):
        """P2G, the grid solves and G2P: the step up to the velocity gradient."""
        c = self.cfg
        g = self.g
        ox, oy = g.ox, g.oy
        K = self.kernels
        K.p2g(self.x, self.y, self.vx, self.vy, self.mass, self.S, self.kind, self.lp, ox, oy,
              self.inv_dx, c.gravity[0], c.gravity[1], self.buf, self.gm, self.gpx, self.gpy,
              self.gfx, self.gfy)
        lap("p2g")
        K.grid_solve(self.gm, self.gpx, self.gpy, self.gfx, self.gfy, dt, True, True, self.fixx,
                     self.fixy, self.etax, self.etay, self.sides, self.bnodes, g.pad,
                     self.mtiny, self.gvx, self.gvy, self.gdx, self.gdy)
        lap("grid_solve x2")
        if K.g2p_velocity_remap(self.x, self.y, self.vx, self.vy, self.mass, self.kind, self.lp,
                                ox, oy, self.inv_dx, self.gvx, self.gvy, self.gdx, self.gdy, dt,
                                c.flip, self.xn, self.yn, self.buf, self.gpx, self.gpy,
                                self.err):
            self._raise_first("grid to particle")
        lap("g2p_velocity + MUSL remap")
        K.grid_solve(self.gm, self.gpx, self.gpy, self.gfx, self.gfy, dt, False, False,
                     self.fixx, self.fixy, self.etax, self.etay, self.sides, self.bnodes, g.pad,
                     self.mtiny, self.gvx, self.gvy, self.gdx, self.gdy)
        lap("grid_solve x2")
        if K.g2p_gradient(self.x, self.y, self.kind, self.lp, ox, oy, self.inv_dx, self.gvx,
                          self.gvy, self.xn, self.yn, self.Lg, self.err):
            self._raise_first("velocity gradient")
        lap("g2p_gradient")

    def _material_phase(self, dt, lap, materials):
        """The update loops of ``materials`` (indices of ``self.loops``); the largest
        c + |v| they find is the next CFL step's speed."""
        c = self.cfg
        g = self.g
        vmax = 0.0
        for k in materials:
            upd = self.loops[k][0]
            nbad, vmat = upd(self.prms[k], self.S, self.solver.mat_index[k], self.Lg, c.q1,
                             c.q2, g.dx, dt, self.t, self.x, self.y, self.vx, self.vy,
                             self.err)
            if nbad:
                self._raise_first("material update")
            vmax = max(vmax, vmat)
            lap(f"material: {self.solver.labels[k]} (+ q, state check, CFL speed)")
        self.vmax = vmax

    def max_speed(self):
        """max (c + |v|) over the particles: from the material loops of the last step, or
        computed (first step)."""
        if self.vmax is None:
            self.vmax = self.kernels.max_speed(self.vx, self.vy, self.S)
        return self.vmax

    def summary(self):
        g = self.g
        n = self.x.size
        return {"steps": int(self.step_no), "dt_min": float(self.dt_used_min),
                "dt_max": float(self.dt_used_max), "wall_time": float(self.wall),
                "particles": int(n), "threads": int(self.nthreads), "cells": int(g.cells), "cell_size": float(g.dx),
                "particle_updates_per_second": float(n * self.step_no / self.wall)
                if self.wall > 0 else 0.0}
