"""Probe time series and energy history of one MPM run.

A probe is a fixed set of particles with weights (``scene.probe_members``, chosen at t = 0):
by default the one particle of the probe's body nearest to the probe point; with ``radius``,
the body's particles within that distance of the point, weighted by a smooth kernel of their
initial distance, so that the value does not jump with the particle layout when the
resolution or the particles per cell change (docs/mpm.md, "Probes"). The set moves with the
material (a Lagrangian gauge, like a gauge glued into the material), so its time series is
the history of a material neighbourhood, without any grid interpolation (which would smear
the steel/water interface). Every quantity is Σ w · (the particle's own value): stresses are
the particles' own states, the deviatoric S11, S22, S12, S33 are σ − tr(σ)/3
(materials/state.py), and the equivalent stress is the weighted mean of the particles' von
Mises stresses (not the von Mises stress of the mean deviator), so that, like every other
quantity, it is linear in the particle values and its parameter derivatives average the same
way.

Samples are taken at the fixed times ``k · output_interval`` (the time loop shortens the step
that would pass a sample time, so a sample is the state exactly at that time).
"""

from __future__ import annotations

import numpy as np

from solvers.mpm.materials import state as ST
from solvers.mpm.scene import ENERGY_OUTPUTS

# the label of each output a figure or a table shows (CF ``long_name``), in plain words; the
# longer definition of a probe quantity is scene.PROBE_QUANTITIES' (the ``description``)
LABELS = {
    "pressure": "pressure",
    "flow_stress": "flow stress",
    "flow_stress_total_rate": "flow stress at the total strain rate",
    "equivalent_stress": "von Mises equivalent stress",
    "S11": "deviatoric stress s_xx",
    "S22": "deviatoric stress s_yy",
    "S12": "shear stress s_xy",
    "S33": "deviatoric stress s_zz",
    "plastic_strain": "equivalent plastic strain",
    "velocity_x": "velocity x",
    "velocity_y": "velocity y",
    "density": "density",
    "temperature": "temperature",
    "burn_fraction": "burn fraction",
    "position_x": "position x",
    "position_y": "position y",
    "kinetic_energy": "kinetic energy",
    "internal_energy": "internal energy",
    "plastic_work": "plastic work",
    "explosive_release": "chemical energy released by the burn",
    "total_energy": "total energy",
    "momentum_x": "momentum x",
    "momentum_y": "momentum y",
}


def probe_values(name, S, vx, vy, x, y, conventions="uqflow"):
    """Quantity ``name`` of the state rows ``S`` (and the matching velocities, positions).
    ``conventions = "seed"`` drops s_zz from the von Mises stress, as seed 000 does."""
    if name == "pressure":
        return S[:, ST.P]
    if name == "flow_stress":
        return S[:, ST.SY]
    if name == "flow_stress_total_rate":
        return S[:, ST.SY_TOTAL_RATE]
    if name in ("S11", "S22", "S12", "S33", "equivalent_stress"):
        d = ST.deviatoric(S)
        if name == "equivalent_stress":
            szz2 = 0.0 if conventions == "seed" else d[:, 3] ** 2
            return np.sqrt(1.5 * (d[:, 0] ** 2 + d[:, 1] ** 2 + szz2 + 2.0 * d[:, 2] ** 2))
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


def _as_members(probes):
    """``[(indices, weights)]`` from ``scene.probe_members``' list, or from an array of one
    particle index per probe (the nearest-particle probes)."""
    if isinstance(probes, np.ndarray) or (len(probes) and np.isscalar(probes[0])):
        return [(np.array([int(i)], dtype=np.int64), np.array([1.0])) for i in probes]
    return [(np.asarray(i, dtype=np.int64), np.asarray(w, dtype=float)) for i, w in probes]


class ProbeRecorder:
    """Probe series and energy history of one run. ``members``: one ``(particle indices,
    weights summing to 1)`` pair per probe, fixed at t = 0 (``scene.probe_members``)."""

    def __init__(self, cfg, members, n_times):
        self.names = tuple(cfg.outputs)
        self.conventions = cfg.conventions
        self.members = _as_members(members)
        n_probes = len(self.members)
        sizes = [i.size for i, _ in self.members]
        self._index = np.concatenate([i for i, _ in self.members] + [np.zeros(0, np.int64)])
        self._weight = np.concatenate([w for _, w in self.members] + [np.zeros(0)])
        self._start = np.concatenate(([0], np.cumsum(sizes)[:-1])).astype(np.int64) \
            if n_probes else np.zeros(0, np.int64)
        self.data = {n: np.full((n_times, n_probes), np.nan) for n in self.names}
        self.energy = {n: np.full(n_times, np.nan) for n in ENERGY_OUTPUTS}
        self.explosives = None      # [(particle index, E0)] of the explosive materials

    def probe_series_values(self, S, vx, vy, x, y):
        """{output name: one value per probe}, Σ w · value over each probe's members. A
        one-member probe gives its particle's value bit for bit (1.0 · v, no summation)."""
        i = self._index
        if i.size == 0:
            return {n: np.zeros(0) for n in self.names}
        rows, vx, vy, x, y = S[i], vx[i], vy[i], x[i], y[i]
        return {n: np.add.reduceat(self._weight * probe_values(n, rows, vx, vy, x, y,
                                                                 self.conventions),
                                   self._start)
                for n in self.names}

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
        for n, v in self.probe_series_values(run.S, run.vx, run.vy, run.x, run.y).items():
            self.data[n][k] = v
        ke, ie, pw, mx, my = run.kernels.energies(run.vx, run.vy, run.mass, run.vol0, run.S)
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
