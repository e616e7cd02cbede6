"""Named materials with their SI data (docs/design/mpm.md, "Materials").

``MATERIALS[name] = (module, defaults)``; ``defaults`` is a dict over ``module.PARAMETERS``.
``material(name, overrides)`` gives ``(module, prm)`` with the packed, checked vector.
"""

from __future__ import annotations

import numpy as np

from uqflow.errors import SceneError

from . import elastic, johnson_cook, jwl, water

STEEL_4340 = {
    "eos.C": 4569.0, "eos.S1": 1.49, "eos.S2": 0.0, "eos.S3": 0.0, "eos.gamma0": 2.17,
    "eos.a": 0.46, "rho0": 7830.0, "shear_modulus": 81.8e9, "jc.A": 792e6, "jc.B": 510e6,
    "jc.n": 0.26, "jc.C": 0.014, "jc.m": 1.03, "jc.eps0_dot": 1.0, "jc.T_room": 294.0,
    "jc.T_melt": 1793.0, "cp": 477.0, "taylor_quinney": 0.9,
}
TNT = {
    "rho0": 1630.0, "D": 6930.0, "eos.A": 371.2e9, "eos.B": 3.231e9, "eos.R1": 4.15,
    "eos.R2": 0.95, "eos.omega": 0.30, "eos.E0": 7.0e9, "det_x": 0.0, "det_y": 0.0,
    "burn_width": 0.0075,
}
WATER = {
    "eos.C": 1480.0, "eos.S1": 2.56, "eos.S2": -1.986, "eos.S3": 0.2268, "eos.gamma0": 0.4934,
    "eos.a": 1.3937, "rho0": 1000.0, "cavitation_pressure": -0.1e6,
}
ELASTIC = {"rho0": 7830.0, "E": 210e9, "nu": 0.286}

MATERIALS = {
    "steel_4340": (johnson_cook, STEEL_4340),
    "tnt": (jwl, TNT),
    "water": (water, WATER),
    "elastic": (elastic, ELASTIC),
}


def material(name: str, overrides: dict | None = None):
    """(module, prm) of a named material with ``overrides`` (dotted parameter names) applied."""
    if name not in MATERIALS:
        raise SceneError(f"unknown material '{name}' (known: {', '.join(MATERIALS)})",
                         key="material")
    module, defaults = MATERIALS[name]
    values = dict(defaults)
    values.update(overrides or {})
    return module, module.pack(values)


def defaults_vector(name: str) -> np.ndarray:
    """The packed default parameter vector of a named material."""
    return material(name)[1]
