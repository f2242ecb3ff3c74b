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
    truth: trajectory.Truth  # internal rate (SUBSTEPS per IMU interval)
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
        return np.arange(trajectory.SUBSTEPS, len(self.truth.t), trajectory.SUBSTEPS)


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
    return Simulation(sc, seed, tr, rate, tr.t[trajectory.SUBSTEPS::trajectory.SUBSTEPS], dtheta, dv, mth, mdv,
                      errors, g)
