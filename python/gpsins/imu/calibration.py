"""Deterministic calibration (the FOI report, 5.1.2, with eqs. 5.2 and 5.5
corrected as docs/references.md gives them).

Accelerometer up-down (eq. 5.2): with the axis up, z1 = b + (1 + s) g; down,
z2 = b - (1 + s) g; so b = (z1 + z2) / 2 and s = (z1 - z2 - 2 g) / (2 g).
Gyro rate table (eq. 5.3-5.5): w_out = (1 + s)(w_table + w_ex) + b, w_ex the
Earth-rate component along the axis; s and b from a least-squares line through
all (table rate, output) pairs, or the bias from a drift test.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import _core


def local_gravity_mps2(lat_rad: float, height_m: float = 0.0) -> float:
    return float(_core.normal_gravity(lat_rad, height_m))


@dataclass
class AxisCalibration:
    bias: float
    scale_factor: float
    residual_rms: float = float("nan")


def accel_up_down(z_up: float, z_down: float, g: float) -> AxisCalibration:
    return AxisCalibration((z_up + z_down) / 2.0, (z_up - z_down - 2.0 * g) / (2.0 * g))


def gyro_rate_table(table_rate: np.ndarray, output: np.ndarray, earth_rate_along_axis: float = 0.0,
                    bias_from_drift_test: float | None = None) -> AxisCalibration:
    """Scale factor (and bias) from (table rate, gyro output) pairs by least squares."""
    x = np.asarray(table_rate, dtype=float) + earth_rate_along_axis
    y = np.asarray(output, dtype=float)
    if bias_from_drift_test is None:
        slope, b = np.polyfit(x, y, 1)
    else:
        b = bias_from_drift_test
        slope = float(np.dot(x, y - b) / np.dot(x, x))
    resid = y - (slope * x + b)
    return AxisCalibration(float(b), float(slope - 1.0), float(np.sqrt(np.mean(resid ** 2))))


def earth_rate_component(lat_rad: float, axis_up: bool) -> float:
    """Earth rate along a vertical (up) axis, or 0 for a horizontal east-pointing one."""
    return 7.292115e-5 * math.sin(lat_rad) if axis_up else 0.0
