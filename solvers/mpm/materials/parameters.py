"""How a material model declares its parameters: one ``ParameterSpec`` per parameter, in the
order of the packed vector, in the model's own module (docs/mpm_materials.md § 1).

The spec table is the only place a parameter's default, SI units and meaning are written:
``PARAMETERS`` (name → default), the solver's ``parameter_units`` and the named materials of
``library.py`` are read from it.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ParameterSpec:
    """One material parameter: dotted ``name``, SI ``default``, ``units`` (CF/UDUNITS text,
    "" for a pure number) and a short ``meaning`` in words."""

    name: str
    default: float
    units: str
    meaning: str


def defaults(specs) -> dict[str, float]:
    """Ordered mapping name → default of a spec table (the packed vector's order)."""
    return {s.name: s.default for s in specs}


def units(specs) -> dict[str, str]:
    """Mapping name → SI units of a spec table."""
    return {s.name: s.units for s in specs}
