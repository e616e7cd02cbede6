"""Local (frozen-state) parameter derivatives of the probe series: the seed's one-run Taylor
method (000, eq. 22–35) on our kernels (docs/mpm_materials.md § 10).

At each output time, for each probe member particle of a Mie–Grüneisen/Johnson–Cook steel,
from the state its last step recorded (state.py: ρ, E; εp, Δεp = EPS_P_RATE·DT, RATE_STAR,
T_RETURN, EQ_STRAIN_RATE; the deviator and SY):

* ``pressure``: ∂p*/∂(S1, S2, S3, γ0, a) at (μ, E), both branches of eq. 10;
* ``flow_stress``: ∂σy/∂(A, B, C, n, m) at (εp, the ε̇* the return used, T* of T_RETURN);
* ``flow_stress_total_rate``: the same at ε̇* of the step's total strain rate;
* ``S11``, ``S22``, ``S12``, ``S33``: the deviator through the consistent tangent of the return
  from the step's fixed trial (``johnson_cook_return_sensitivities``), 0 in elastic steps.

First and second derivatives; a probe's are Σ w · (its members' particle derivatives), as its
value is. A particle has derivatives only with respect to its own material's parameters: a
probe member in the water (or any material that is not the MG–JC steel) contributes exactly
0, as does every (output, parameter) pair without a local dependence (pressure wrt the JC
constants, the stresses wrt the EOS ones). History quantities (plastic strain, velocities,
energies, density, temperature) have no local derivative: they are sums over the steps, which
the frozen state does not differentiate.
"""

from __future__ import annotations

import numpy as np

from solvers.mpm.materials import johnson_cook as JC, mie_gruneisen as MG, state as ST
from solvers.mpm.materials.johnson_cook import (johnson_cook_return_sensitivities,
                                                johnson_cook_sensitivities)
from solvers.mpm.materials.mie_gruneisen import mie_gruneisen_sensitivities

# each model's differentiable parameters, as the model declares them
MG_PARAMETERS = MG.DIFFERENTIABLE_PARAMETERS
JC_PARAMETERS = JC.DIFFERENTIABLE_PARAMETERS

LOCAL_PARAMETERS = MG_PARAMETERS + JC_PARAMETERS          # a steel particle's derivatives
EOS_SLOTS = slice(0, len(MG_PARAMETERS))                   # where each model's land in them
FLOW_SLOTS = slice(len(MG_PARAMETERS), len(LOCAL_PARAMETERS))
# the flow-stress parameters' places in the steel's packed vector, in JC_PARAMETERS order
FLOW_INDEX = [list(JC.PARAMETERS).index(name) for name in JC_PARAMETERS]
DEVIATOR_COLUMN = {"S11": 0, "S22": 1, "S12": 2, "S33": 3}   # of state.deviatoric
OUTPUTS = ("pressure", "flow_stress", "flow_stress_total_rate", *DEVIATOR_COLUMN)


def steel_labels(solver):
    """Labels of the scene's materials with the MG–JC steel model, in the solver's order."""
    return [lab for lab in solver.labels if solver.cfg.materials[lab].module is JC]


def sensitivity_parameters(solver):
    """``<label>.<parameter>`` of every parameter with a local derivative, per steel label."""
    return tuple(f"{lab}.{p}" for lab in steel_labels(solver) for p in LOCAL_PARAMETERS)


def return_tangent(rows, prm):
    """(∂σ̄/∂θ (N, 5), ∂²σ̄/∂θ² (N, 5, 5)), θ = JC_PARAMETERS, of the flow stress each row's
    last return reached, from its fixed trial (0 for elastic steps): what every deviator
    component scales."""
    return johnson_cook_return_sensitivities(
        *prm[FLOW_INDEX], prm[JC.I_G], rows[:, ST.EPS_P],
        rows[:, ST.EPS_P_RATE] * rows[:, ST.DT], rows[:, ST.RATE_STAR], return_T_star(rows, prm),
        rate_fixed=prm[JC.I_SEED] != 0.0)


def return_T_star(rows, prm):
    """T* of the temperature the rows' last return used (before that step's heating)."""
    return (rows[:, ST.T_RETURN] - prm[JC.I_TROOM]) / (prm[JC.I_TMELT] - prm[JC.I_TROOM])


def particle_derivatives(output, rows, prm, tangent=None):
    """(gradient (N, L), Hessian (N, L, L)) of ``output`` for state rows of one steel
    material with packed parameters ``prm``, in LOCAL_PARAMETERS order. ``tangent``: the
    rows' ``return_tangent``, when already computed (the four deviator components share it)."""
    n_rows = rows.shape[0]
    grad = np.zeros((n_rows, len(LOCAL_PARAMETERS)))
    hess = np.zeros((n_rows, len(LOCAL_PARAMETERS), len(LOCAL_PARAMETERS)))
    seed = prm[JC.I_SEED] != 0.0
    if output == "pressure":
        rho0 = prm[JC.I_RHO0]
        _, g, h = mie_gruneisen_sensitivities(rows[:, ST.RHO] / rho0 - 1.0, rows[:, ST.E], rho0,
                                              *prm[[JC.I_C, JC.I_S1, JC.I_S2, JC.I_S3,
                                                    JC.I_G0, JC.I_A]])
        grad[:, EOS_SLOTS], hess[:, EOS_SLOTS, EOS_SLOTS] = g, h
    elif output in ("flow_stress", "flow_stress_total_rate"):
        rate = (rows[:, ST.RATE_STAR] if output == "flow_stress"
                else rows[:, ST.EQ_STRAIN_RATE] / prm[JC.I_EPS0])
        _, g, h = johnson_cook_sensitivities(*prm[FLOW_INDEX], rows[:, ST.EPS_P], rate,
                                             return_T_star(rows, prm), rate_clamped=not seed)
        grad[:, FLOW_SLOTS], hess[:, FLOW_SLOTS, FLOW_SLOTS] = g, h
    else:
        g, h = return_tangent(rows, prm) if tangent is None else tangent
        s = ST.deviatoric(rows)[:, DEVIATOR_COLUMN[output]]
        sy = rows[:, ST.SY]
        ratio = np.divide(s, sy, out=np.zeros_like(s), where=sy != 0.0)   # s*_ij/σeq*
        grad[:, FLOW_SLOTS] = ratio[:, None] * g
        hess[:, FLOW_SLOTS, FLOW_SLOTS] = ratio[:, None, None] * h
    return grad, hess


class ProbeSensitivities:
    """Gradient and Hessian series of ``outputs`` wrt ``wrt`` at every probe, recorded at the
    output times from the state the time loop left (``record``, beside ProbeRecorder.record)."""

    def __init__(self, solver, prms, members, wrt, outputs, n_times):
        self.outputs = tuple(outputs)
        self.prms = prms
        position = {name: k for k, name in enumerate(wrt)}
        n_probes, n_wrt = len(members), len(wrt)
        # per steel material: its members' (probe, particle, weight) and where its local
        # parameters land in ``wrt`` (−1: not asked for)
        self.groups = []
        material = solver.parts.material
        for lab in steel_labels(solver):
            k = solver.labels.index(lab)
            probe, index, weight = [], [], []
            for j, (idx, w) in enumerate(members):
                mine = material[idx] == k
                probe += [j] * int(mine.sum())
                index += list(idx[mine])
                weight += list(w[mine])
            slots = np.array([position.get(f"{lab}.{p}", -1) for p in LOCAL_PARAMETERS])
            if index and np.any(slots >= 0):
                self.groups.append((k, np.array(probe), np.array(index, dtype=np.int64),
                                    np.array(weight), slots))
        self.gradient = {o: np.zeros((n_times, n_probes, n_wrt)) for o in self.outputs}
        self.hessian = {o: np.zeros((n_times, n_probes, n_wrt, n_wrt)) for o in self.outputs}

    def record(self, k, run):
        for material, probe, index, weight, slots in self.groups:
            keep = np.flatnonzero(slots >= 0)
            cols = slots[keep]
            rows = run.S[index]
            prm = self.prms[material]
            tangent = (return_tangent(rows, prm)
                       if any(o in DEVIATOR_COLUMN for o in self.outputs) else None)
            for o in self.outputs:
                g, h = particle_derivatives(o, rows, prm, tangent)
                np.add.at(self.gradient[o][k], (probe[:, None], cols[None, :]),
                          weight[:, None] * g[:, keep])
                np.add.at(self.hessian[o][k], (probe[:, None, None], cols[None, :, None],
                                               cols[None, None, :]),
                          weight[:, None, None] * h[:, keep][:, :, keep])
