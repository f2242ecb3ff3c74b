"""A simulated unit drawn from what its user knows: the datasheet and the calibration
with its uncertainty. The filter is configured from the same description
(``filter_overrides``), never from the drawn unit, so tests see the model mismatch
a real campaign has: scale factors off their calibration, a bias off its
calibrated value, misalignment the filter knows only by its sigma, g-sensitivity
it does not model, and noise coefficients that differ from the figures the filter
was tuned with.

Default figures: the report's calibration (Tables 5.1, 5.5) and Allan noise
(Tables 5.8, 5.9); the calibration uncertainties are this project's estimates of
what a turntable and up-down test leave (0.2 % gyro and 0.1 % accelerometer scale
factor, the turn-on repeatability for the biases, 1 mrad misalignment); the gyro
g-sensitivity is the ADXRS300 datasheet's typical 0.2 deg/s/g per element.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from .scenario import ImuModel

DEG = np.pi / 180.0
G0 = 9.80665


@dataclass
class Datasheet:
    gyro_bias_cal_rad_per_s: tuple = (0.0003962, 0.0146681, 0.0195939)
    accel_bias_cal_mps2: tuple = (0.2899, 0.2312, 0.1928)
    gyro_scale_factor_cal: tuple = (-0.0020, -0.0042, -0.0017)
    accel_scale_factor_cal: tuple = (-4.7856e-4, -0.0014, -0.0031)
    # Calibration uncertainty (1 sigma).
    gyro_bias_sigma_rad_per_s: float = 2e-3
    accel_bias_sigma_mps2: float = 0.03
    gyro_scale_factor_sigma: float = 2e-3
    accel_scale_factor_sigma: float = 1e-3
    misalignment_sigma_rad: float = 1e-3
    gyro_g_sensitivity_rad_per_s_per_mps2: float = 0.2 * DEG / G0
    # Noise figures (Allan; by default the report's Tables 5.8 and 5.9, as the simulator's IMU model has
    # them): the filter is tuned with these; the unit's own are drawn around them.
    gyro_arw_rad_per_sqrt_s: tuple = ImuModel.gyro_arw_rad_per_sqrt_s
    gyro_bias_instability_rad_per_s: tuple = ImuModel.gyro_bias_instability_rad_per_s
    gyro_rrw_rad_per_s_sqrt_s: tuple = ImuModel.gyro_rrw_rad_per_s_sqrt_s
    accel_vrw_mps_per_sqrt_s: tuple = ImuModel.accel_vrw_mps_per_sqrt_s
    accel_bias_instability_mps2: tuple = ImuModel.accel_bias_instability_mps2
    accel_rrw_mps2_per_sqrt_s: tuple = ImuModel.accel_rrw_mps2_per_sqrt_s
    noise_spread: float = 0.2  # the unit's coefficients: datasheet x lognormal(0, spread)


NOISE = ("gyro_arw_rad_per_sqrt_s", "gyro_bias_instability_rad_per_s", "gyro_rrw_rad_per_s_sqrt_s",
         "accel_vrw_mps_per_sqrt_s", "accel_bias_instability_mps2", "accel_rrw_mps2_per_sqrt_s")


def draw_unit(ds: Datasheet, rng: np.random.Generator, base: ImuModel | None = None) -> ImuModel:
    """A unit's true error model: scale factors drawn around the calibration, noise
    coefficients around the datasheet; the turn-on bias (calibrated value + a residual of the
    calibration's sigma), misalignment and g-sensitivity are drawn by the simulator from the
    returned model's sigmas, per seed."""
    m = copy.deepcopy(base) if base is not None else ImuModel()
    m.gyro_scale_factor = tuple(np.asarray(ds.gyro_scale_factor_cal) + rng.normal(0.0, ds.gyro_scale_factor_sigma, 3))
    m.accel_scale_factor = tuple(np.asarray(ds.accel_scale_factor_cal)
                                 + rng.normal(0.0, ds.accel_scale_factor_sigma, 3))
    m.gyro_bias_rad_per_s = tuple(ds.gyro_bias_cal_rad_per_s)
    m.accel_bias_mps2 = tuple(ds.accel_bias_cal_mps2)
    m.gyro_bias_residual_rad_per_s = ds.gyro_bias_sigma_rad_per_s
    m.accel_bias_residual_mps2 = ds.accel_bias_sigma_mps2
    m.gyro_misalignment_rad = m.accel_misalignment_rad = ds.misalignment_sigma_rad
    m.gyro_g_sensitivity_rad_per_s_per_mps2 = ds.gyro_g_sensitivity_rad_per_s_per_mps2
    for k in NOISE:
        m.__dict__[k] = tuple(np.asarray(getattr(ds, k)) * np.exp(rng.normal(0.0, ds.noise_spread, 3)))
    return m


def filter_overrides(ds: Datasheet, scale_factor_states: bool = True) -> dict:
    """Filter configuration keys from the datasheet and calibration alone (gpsins.nav.config names)."""
    out = {
        "gyro_bias_cal_rad_per_s": list(ds.gyro_bias_cal_rad_per_s),
        "accel_bias_cal_mps2": list(ds.accel_bias_cal_mps2),
        "gyro_scale_factor_cal": list(ds.gyro_scale_factor_cal),
        "accel_scale_factor_cal": list(ds.accel_scale_factor_cal),
        "gyro_bias_residual_rad_per_s": ds.gyro_bias_sigma_rad_per_s,
        "accel_bias_residual_mps2": ds.accel_bias_sigma_mps2,
        "gyro_misalignment_sigma_rad": ds.misalignment_sigma_rad,
        "imu_noise": {k: list(getattr(ds, k)) for k in NOISE},
    }
    if scale_factor_states:
        out.update(scale_factor_states=True, gyro_scale_factor_sigma=[ds.gyro_scale_factor_sigma] * 3,
                   accel_scale_factor_sigma=[ds.accel_scale_factor_sigma] * 3)
    return out


@dataclass
class ReceiverErrors:
    """What the user assumes of the GNSS receiver's errors in open sky: a white part and a part
    correlated over tens of seconds (multipath, ionosphere and troposphere residuals), which the
    preset's white models leave out. Loose: the preset's split of the fix error (white UERE 2 m,
    Gauss-Markov 1.5/1.5/2.5 m north/east/down over 60 s). Tight: 1 m white per pseudorange and a
    code multipath of 0.6 m at zenith growing as 1 / sin(elevation), correlated over 20 s (the
    simulated receiver's figures, of the order published for low-cost receivers in open sky)."""

    fix_uere_m: float = 2.0
    fix_error_gm_sigma_m: tuple = (1.5, 1.5, 2.5)
    fix_error_gm_tau_s: float = 60.0
    pseudorange_sigma_m: float = 1.0
    pseudorange_error_gm_sigma_m: float = 0.6
    pseudorange_error_gm_tau_s: float = 20.0


def receiver_overrides(rx: ReceiverErrors, mode: str) -> dict:
    """Filter configuration keys for the receiver's correlated errors in `mode` (loose or tight)."""
    if mode == "tight":
        return {"pseudorange_sigma_m": rx.pseudorange_sigma_m,
                "pseudorange_error_gm_sigma_m": rx.pseudorange_error_gm_sigma_m,
                "pseudorange_error_gm_tau_s": rx.pseudorange_error_gm_tau_s}
    return {"fix_uere_m": rx.fix_uere_m, "fix_error_gm_sigma_m": list(rx.fix_error_gm_sigma_m),
            "fix_error_gm_tau_s": rx.fix_error_gm_tau_s}
