"""What an engineer reads on the MPM outputs: a plain label (``long_name``) and SI ``units``
on every output of ``outputs()`` and of ``run``'s dataset, and each probe's position as the
coordinates ``probe_x``, ``probe_y`` of dim ``probe``."""

from __future__ import annotations

import numpy as np

from solvers.mpm import MPMSolver
from solvers.mpm.scene import PROBE_QUANTITIES

SI_UNITS = {"Pa", "1", "m", "m s-1", "kg m-3", "K", "J m-1", "kg s-1", "s"}


def _scene():
    return dict(domain=dict(x=[0.0, 0.1], y=[0.0, 0.1]), cell_size=0.01, particles_per_cell=2,
                materials=dict(m=dict(model="elastic", rho0=1000.0, E=1e6, nu=0.3)),
                bodies=[dict(name="block", material="m", shape="rectangle", min=[0.02, 0.02],
                             max=[0.08, 0.08], velocity=[1.0, 0.0])],
                end_time=0.001, output_interval=0.0005, outputs=list(PROBE_QUANTITIES),
                probes=[dict(name="H", point=[0.05, 0.045], body="block"),
                        dict(name="I", point=[0.03, 0.07], body="block")])


def _check(ds):
    for name in list(ds.data_vars):
        attrs = ds[name].attrs
        assert attrs.get("units") in SI_UNITS, (name, attrs)
        label = attrs.get("long_name", "")
        assert label and "_" not in label.replace("s_x", "").replace("s_y", "").replace(
            "s_z", ""), (name, label)                  # words, not a variable name
        assert len(label) <= 40, (name, label)         # a label, not a definition
    assert ds["S11"].attrs["long_name"] == "deviatoric stress s_xx"
    assert ds["S22"].attrs["long_name"] == "deviatoric stress s_yy"
    assert ds["flow_stress"].attrs["long_name"] == "flow stress"
    assert ds["plastic_strain"].attrs["long_name"] == "equivalent plastic strain"
    assert ds["pressure"].attrs["long_name"] == "pressure"
    assert ds["kinetic_energy"].attrs["long_name"] == "kinetic energy"
    assert ds["internal_energy"].attrs["long_name"] == "internal energy"
    for axis, values in (("x", [0.05, 0.03]), ("y", [0.045, 0.07])):
        coord = ds[f"probe_{axis}"]
        assert coord.dims == ("probe",)
        assert coord.attrs == {"units": "m", "long_name": axis}
        assert coord.values.tolist() == values       # the scene's points, as given
    assert ds["probe"].values.tolist() == ["H", "I"]


def test_every_output_has_a_plain_label_and_si_units():
    solver = MPMSolver.from_scene(_scene())
    _check(solver.outputs())
    result = solver.run({})
    _check(result)
    assert np.isfinite(result["S11"].values).all()
