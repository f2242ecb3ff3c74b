"""The drive simulator: the project's ground truth.

``simulate(scenario, seed)`` gives the truth trajectory, the IMU's increments
with every error term's true value, and the receiver's measurements and fixes.
It uses its own NumPy models throughout (never the C++ core's), so a mistake
shared with the filter cannot hide. ``session.write_session`` turns a
simulation into a logger session directory; ``messages.SimSource`` serves it
to the pty emulators.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import gnss, imu, trajectory
from .scenario import Scenario, load

__all__ = ["Simulation", "simulate", "load", "Scenario"]


@dataclass
class Simulation:
    scenario: Scenario
    seed: int
    truth: trajectory.Truth  # internal rate (truth.substeps per IMU interval)
    imu_rate_hz: int
    imu_t: np.ndarray  # (n,) true run time of each IMU sampling instant
    ideal_dtheta: np.ndarray  # (n, 3) error-free increments
    ideal_dv: np.ndarray
    imu_dtheta: np.ndarray  # (n, 3) as the unit reports them (before quantisation)
    imu_dv: np.ndarray
    imu_errors: imu.ImuErrors
    gnss: gnss.GnssSim

    @property
    def truth_at_imu(self) -> np.ndarray:
        """Indices of the internal truth samples at the IMU's sampling instants."""
        sub = self.truth.substeps
        return np.arange(sub, len(self.truth.t), sub)


def simulate(sc: Scenario, seed: int = 0) -> Simulation:
    rng = np.random.default_rng([seed, 0x9E3779B9])
    rate = sc.imu.rate_hz
    # The IMU's own clock runs fast by imu_clock_ppm: its samples come that much more often.
    period = 1.0 / (rate * (1.0 + 1e-6 * sc.timing.imu_clock_ppm))
    phase = float(rng.uniform(0.0, period))  # the IMU does not sample on GPS seconds
    n = int((sc.duration_s - phase) / period)
    tr = trajectory.truth(sc, phase + period, 1.0 / period, n)
    dtheta, dv = trajectory.ideal_increments(tr)
    imu_rng = np.random.default_rng([seed, sc.imu.seed_offset])
    errors = imu.draw_errors(sc.imu, n, imu_rng)
    mth, mdv = imu.measure(dtheta, dv, sc.imu, errors, imu_rng)
    g = gnss.simulate(sc, tr, np.random.default_rng([seed, 2]))
    return Simulation(sc, seed, tr, rate, tr.t[tr.substeps::tr.substeps], dtheta, dv, mth, mdv, errors, g)


def imu_table(s: Simulation) -> np.ndarray:
    """(n, 7) [t, dtheta xyz, dv xyz]: the unit's increments on the true time line."""
    return np.column_stack([s.imu_t, s.imu_dtheta, s.imu_dv])


def fix_table(s: Simulation) -> np.ndarray:
    """(m, 10) [t, r xyz, v xyz, hdop, vdop, mode]: the receiver's fixes on the true time line."""
    return np.array([[f.t, *f.r_ecef, *f.v_ecef, f.hdop, f.vdop, f.mode] for f in s.gnss.fixes]).reshape(-1, 10)


NOISE_KEYS = ("gyro_arw_rad_per_sqrt_s", "gyro_bias_instability_rad_per_s", "gyro_rrw_rad_per_s_sqrt_s",
              "accel_vrw_mps_per_sqrt_s", "accel_bias_instability_mps2", "accel_rrw_mps2_per_sqrt_s")


def imu_noise_truth(model) -> dict:
    """The drawn unit's noise coefficients and turn-on residuals, named as the filter's
    configuration names them (``[imu_noise]`` and ``*_bias_residual_*``).

    ``model``: the scenario's ImuModel, or the ``imu`` table of a truth file's model.
    """
    get = model.get if isinstance(model, dict) else lambda k: getattr(model, k)
    noise = {k: [float(x) for x in get(k)] for k in NOISE_KEYS}
    terms = get("terms")
    for flag, keys in (("white_noise", ("gyro_arw_rad_per_sqrt_s", "accel_vrw_mps_per_sqrt_s")),
                       ("bias_instability", ("gyro_bias_instability_rad_per_s", "accel_bias_instability_mps2")),
                       ("rate_random_walk", ("gyro_rrw_rad_per_s_sqrt_s", "accel_rrw_mps2_per_sqrt_s"))):
        if not terms[flag]:
            for k in keys:
                noise[k] = [0.0, 0.0, 0.0]
    on = terms["turn_on_bias"]
    return {"imu_noise": noise,
            "gyro_bias_residual_rad_per_s": float(get("gyro_bias_residual_rad_per_s")) if on else 0.0,
            "accel_bias_residual_mps2": float(get("accel_bias_residual_mps2")) if on else 0.0}


def pseudorange_table(s: Simulation) -> np.ndarray:
    """(k, 5) [t, prn, pseudorange, C/N0, lock count] per tracked satellite, t the receiver's
    time of the epoch on the run's time line (tow_rx - start tow)."""
    g = s.gnss
    k, j = np.nonzero(g.tracked)
    t = g.tow_rx[k] - s.scenario.start.gps_tow_s
    return np.column_stack([t, j + 1, g.pseudorange_m[k, j], g.cn0_dbhz[k, j], g.lock_count[k, j]])
