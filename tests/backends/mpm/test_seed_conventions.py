"""The scene option ``conventions = "seed"`` in the Johnson–Cook kernel (docs/mpm_materials.md
§ 3a), and the default (``"uqflow"``) left bit for bit as it was."""

from __future__ import annotations

import hashlib
import tomllib
from pathlib import Path

import numpy as np
import pytest

from solvers.mpm.solver import MPMSolver, _Run

REPO = Path(__file__).resolve().parents[3]
REFERENCE = REPO / "tests/data/mpm_uqflow_reference.npz"
REFERENCE_OUTPUTS = ["pressure", "flow_stress", "S11", "S22", "S12", "S33", "plastic_strain",
                     "temperature", "velocity_x"]


def small_scene(**over):
    sc = tomllib.loads((REPO / "studies/scenes/mpm_contact_thin_small.toml").read_text())
    sc.update(resolution=0.5, end_time=8e-6, output_interval=1e-6, threads=1)
    sc.update(over)
    return sc


def test_uqflow_conventions_are_bitwise_unchanged():
    """tests/data/mpm_uqflow_reference.npz was written by the code before the state columns
    and the seed conventions existed (commit a1e4f98; the scene below, one thread): the probe
    series and a SHA-256 of the final positions, velocities and the first 15 state columns
    (the layout then) must be reproduced bit for bit."""
    ref = np.load(REFERENCE)
    sc = small_scene(end_time=15e-6, output_interval=0.5e-6, outputs=REFERENCE_OUTPUTS)
    sol = MPMSolver.from_scene(sc)
    ds = sol.run({})
    for name in REFERENCE_OUTPUTS + ["total_energy"]:
        assert np.array_equal(ds[name].values, ref[name]), name
    run = _Run(sol, sol._parameters({}))
    run.advance()
    digest = hashlib.sha256(np.ascontiguousarray(run.S[:, :15]).tobytes() + run.x.tobytes()
                            + run.y.tobytes() + run.vx.tobytes() + run.vy.tobytes()).hexdigest()
    assert digest == str(ref["state_sha256"])
