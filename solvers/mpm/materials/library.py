"""Named materials: the name a scene gives (``material = "steel_4340"``) → its model module.

``MATERIALS[name] = (module, defaults)``; ``defaults`` is the module's own ``PARAMETERS``
(each model's defaults are the named material's data: docs/design/mpm.md, "Materials"), so a
default is written once, in the model's spec table. ``material(name, overrides)`` gives
``(module, prm)`` with the packed, checked vector.
"""

from __future__ import annotations

from uqflow.errors import SceneError

from . import elastic, johnson_cook, jwl, water

MATERIALS = {
    "steel_4340": (johnson_cook, johnson_cook.PARAMETERS),   # AISI 4340 (seed Tables 2, 5)
    "tnt": (jwl, jwl.PARAMETERS),                            # Dobratz & Crawford 1985
    "water": (water, water.PARAMETERS),                      # LS-DYNA UNDEX set
    "elastic": (elastic, elastic.PARAMETERS),
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
