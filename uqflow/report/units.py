"""Display units: the scale a figure or a title shows a quantity in (2.3e9 Pa as 2.3 GPa,
0.12 m as 120 mm), and the label a reader understands ("deviatoric stress s_xx [GPa]").

Only the units themselves are scaled; the stored values and the tables stay in SI.
"""

from __future__ import annotations

import math

import numpy as np
import xarray as xr

from uqflow.layout import LONG_NAME, UNITS

#: SI prefixes by power of ten (the engineering ones: steps of 10^3)
PREFIXES = {-12: "p", -9: "n", -6: "µ", -3: "m", 0: "", 3: "k", 6: "M", 9: "G", 12: "T"}

#: units a prefix is put in front of, and the largest power each takes (seconds stay seconds
#: above 1: a kilosecond reads worse than 1000 s)
PREFIXED_UNITS = {"Pa": 12, "m": 3, "s": 0, "J": 12, "N": 12, "W": 12, "V": 9, "A": 6,
                  "Hz": 12}


def display_units(values, units: str) -> tuple[float, str]:
    """``(scale, label)``: show ``values`` (any array-like, in ``units``) as ``values * scale``
    in ``label``, with the SI prefix that puts the largest finite magnitude between 1 and 1000
    ("Pa" with values up to 2.3e9: (1e-9, "GPa")). Units without a prefix rule, and values
    with no finite non-zero magnitude (empty, all zero, NaN or inf), stay as they are:
    ``(1.0, units)``."""
    units = str(units or "")
    largest_power = PREFIXED_UNITS.get(units)
    if largest_power is None:
        return 1.0, units
    magnitude = np.abs(np.asarray(values, dtype=float)).ravel()
    magnitude = magnitude[np.isfinite(magnitude) & (magnitude > 0)]
    if magnitude.size == 0:
        return 1.0, units
    power = 3 * math.floor(math.log10(float(magnitude.max())) / 3)
    power = max(min(power, largest_power, max(PREFIXES)), min(PREFIXES))
    return 10.0 ** -power, PREFIXES[power] + units


def long_name(variable: xr.DataArray | None, name: str) -> str:
    """What a variable is, in words: its ``long_name`` attribute, else its name."""
    if variable is not None and str(variable.attrs.get(LONG_NAME, "")).strip():
        return str(variable.attrs[LONG_NAME]).strip()
    return str(name)


def units_attr(variable: xr.DataArray | None) -> str:
    return str(variable.attrs.get(UNITS, "")) if variable is not None else ""


def quantity_label(name: str, units: str) -> str:
    """'deviatoric stress s_xx [GPa]'; units '' or '-' give no brackets but '[-]' is kept
    for a dimensionless quantity a solver marked so."""
    return f"{name} [{units}]" if units else name


def format_value(value: float, scale: float = 1.0) -> str:
    """A coordinate value for a title: 4 significant digits after scaling."""
    try:
        value = float(value) * scale
    except (TypeError, ValueError):
        return str(value)
    return f"{value:.4g}"
