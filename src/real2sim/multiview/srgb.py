"""The sRGB encoding of the datasets' 8-bit images (IEC 61966-2-1), values in [0, 1].

Cameras change exposure and white balance by gains in linear light, before this encoding: a
capture applies such gains (:mod:`real2sim.capture.sim.hard_rigs`) and the reconstruction takes
them out (:mod:`real2sim.reconstruct.carving.view_exposure`), both through these two functions.
Floating-point inputs keep their dtype; values below 0 or above 1 pass through without NaNs.
"""

from __future__ import annotations

import numpy as np


def _floating(values) -> np.ndarray:
    values = np.asarray(values)
    return values if np.issubdtype(values.dtype, np.floating) else values.astype(np.float64)


def srgb_to_linear(srgb) -> np.ndarray:
    """sRGB-encoded values to linear light."""
    srgb = _floating(srgb)
    return np.where(srgb <= 0.04045, srgb / 12.92, ((np.maximum(srgb, 0.04045) + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(linear) -> np.ndarray:
    """Linear light to sRGB encoding (values above 1 stay above 1)."""
    linear = _floating(linear)
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.maximum(linear, 0.0031308) ** (1 / 2.4) - 0.055)
