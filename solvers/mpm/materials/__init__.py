"""Material kernels of the MPM solver (plane strain): state layout, error codes and one module
per model. Each model module exposes ``NAME``, ``PARAMETERS`` (ordered dotted names → SI
defaults), ``HAS_STRENGTH``, ``pack(values) -> prm``, ``check(prm)`` and the numba kernels
``init(prm, S, i) -> int`` and ``update(prm, S, i, Lxx, Lxy, Lyx, Lyy, dt, time, x, y) -> int``.
See docs/mpm_materials.md.
"""

from . import elastic, johnson_cook, jwl, mie_gruneisen, state, water
from .library import MATERIALS, material
from .state import (ERR_DENSITY, ERR_MG_DENOMINATOR, ERR_NONFINITE, ERR_OTHER, ERR_SHAPE,
                    N_STATE, OK, error_text, solver_error)

__all__ = ["MATERIALS", "material", "state", "elastic", "johnson_cook", "jwl", "mie_gruneisen",
           "water", "N_STATE", "OK", "ERR_NONFINITE", "ERR_DENSITY", "ERR_MG_DENOMINATOR",
           "ERR_OTHER", "ERR_SHAPE", "error_text", "solver_error"]
