"""Smoothing kernels of the corrected SPH, support radius 2h (docs/sph.md, "Kernel").

The correction (``interpolation``) removes every normalisation constant, so a kernel here
only needs its shape: positive inside the support, zero with a zero slope at r = 2h.
"""

from __future__ import annotations

import numpy as np

KERNELS = ("cubic_spline", "wendland_c2")


def kernel(name: str, r: np.ndarray, h: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """W(r, h) and dW/dr of kernel ``name`` (2-D normalisation), zero for r >= 2h."""
    q = np.asarray(r, dtype=float) / h
    if name == "cubic_spline":
        sigma = 10.0 / (7.0 * np.pi * np.square(h))
        near = q < 1.0
        far = 2.0 - q
        w = np.where(near, 1.0 - 1.5 * q * q + 0.75 * q ** 3, 0.25 * far ** 3)
        dw = np.where(near, -3.0 * q + 2.25 * q * q, -0.75 * far * far)
    elif name == "wendland_c2":
        sigma = 7.0 / (4.0 * np.pi * np.square(h))
        t = 1.0 - 0.5 * q
        w = t ** 4 * (2.0 * q + 1.0)
        dw = -5.0 * q * t ** 3
    else:
        raise ValueError(f"unknown kernel {name!r} (known: {', '.join(KERNELS)})")
    inside = q < 2.0
    return np.where(inside, sigma * w, 0.0), np.where(inside, sigma * dw / h, 0.0)
