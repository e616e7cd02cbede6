"""Probe time series and energy history of one MPM run.

A probe is a particle: the particle of the probe's body nearest to the probe point at t = 0
(``scene.place_probes``). It moves with the material (a Lagrangian gauge, like a gauge glued
into the material), so its time series is the history of one material point, without any
grid interpolation (which would smear the steel/water interface). Stresses are the particle's
own state; the deviatoric S11, S22, S12, S33 are σ − tr(σ)/3 (materials/state.py).

Samples are taken at the fixed times ``k · output_interval`` (the time loop shortens the step
that would pass a sample time, so a sample is the state exactly at that time).
"""

from __future__ import annotations

import numpy as np

from solvers.mpm import step as K
from solvers.mpm.materials import state as ST
from solvers.mpm.scene import ENERGY_OUTPUTS


def probe_values(name, S, vx, vy, x, y):
    """Quantity ``name`` of the state rows ``S`` (and the matching velocities, positions)."""
    if name == "pressure":
        return S[:, ST.P]
    if name == "flow_stress":
        return S[:, ST.SY]
    if name in ("S11", "S22", "S12", "S33", "equivalent_stress"):
        d = ST.deviatoric(S)
        if name == "equivalent_stress":
            return np.sqrt(1.5 * (d[:, 0] ** 2 + d[:, 1] ** 2 + d[:, 3] ** 2
                                  + 2.0 * d[:, 2] ** 2))
        return d[:, {"S11": 0, "S22": 1, "S12": 2, "S33": 3}[name]]
    if name == "plastic_strain":
        return S[:, ST.EPS_P]
    if name == "velocity_x":
        return vx
    if name == "velocity_y":
        return vy
    if name == "density":
        return S[:, ST.RHO]
    if name == "temperature":
        return S[:, ST.T]
    if name == "burn_fraction":
        return S[:, ST.BURN]
    if name == "position_x":
        return x
    if name == "position_y":
        return y
    raise KeyError(name)


class ProbeRecorder:
    def __init__(self, cfg, probe_index, n_times):
        self.names = tuple(cfg.outputs)
        self.idx = np.asarray(probe_index, dtype=np.int64)
        n_probes = self.idx.size
        self.data = {n: np.full((n_times, n_probes), np.nan) for n in self.names}
        self.energy = {n: np.full(n_times, np.nan) for n in ENERGY_OUTPUTS}
        self.explosives = None      # [(particle index, E0)] of the explosive materials

    def _explosives(self, run):
        """(particle indices, chemical energy E0 per reference volume) of every material
        whose module names a ``CHEMICAL_ENERGY`` parameter."""
        out = []
        for k, lab in enumerate(run.solver.labels):
            module = run.cfg.materials[lab].module
            name = getattr(module, "CHEMICAL_ENERGY", None)
            if name is not None:
                e0 = float(run.prms[k][list(module.PARAMETERS).index(name)])
                out.append((run.solver.mat_index[k], e0))
        return out

    def record(self, k, run):
        i = self.idx
        S = run.S[i]
        for n in self.names:
            self.data[n][k] = probe_values(n, S, run.vx[i], run.vy[i], run.x[i], run.y[i])
        ke, ie, pw, mx, my = K.energies(run.vx, run.vy, run.mass, run.vol0, run.S)
        self.energy["momentum_x"][k] = mx
        self.energy["momentum_y"][k] = my
        self.energy["kinetic_energy"][k] = ke
        self.energy["internal_energy"][k] = ie
        self.energy["plastic_work"][k] = pw
        if self.explosives is None:
            self.explosives = self._explosives(run)
        # chemical energy the burn has made available so far (it is part of E from t = 0)
        self.energy["explosive_release"][k] = sum(
            e0 * float(np.dot(run.S[idx, ST.BURN], run.vol0[idx]))
            for idx, e0 in self.explosives)
        self.energy["total_energy"][k] = ke + ie

    def results(self):
        out = dict(self.data)
        out.update(self.energy)
        return out
