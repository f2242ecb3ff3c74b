"""The drive simulator: the project's ground truth.

``simulate(scenario, seed)`` gives the truth trajectory, the IMU's increments
with every error term's true value, and the receiver's measurements and fixes.
``Simulator(scenario, seed).blocks(block_s)`` gives the same run as consecutive
time blocks in bounded memory, identical whatever the block size: every random
draw is addressed by its sample or epoch (``draws``) and every process carries
its state across block ends. It uses its own NumPy models throughout (never the
C++ core's), so a mistake shared with the filter cannot hide.
``session.write_session`` turns a simulation into a logger session directory
(``session.simulate_session`` block by block); ``messages.SimSource`` serves it
to the pty emulators.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from . import gnss, imu, reference, trajectory
from .draws import Stream
from .scenario import Scenario, load
from ..formats.gpstime import SECONDS_PER_WEEK

__all__ = ["Simulation", "Simulator", "simulate", "load", "Scenario"]

DEFAULT_BLOCK_S = 60.0


@dataclass
class Simulation:
    """A run, or one time block of it (``imu_i0`` its first IMU sample, ``gnss.k0`` its first receiver epoch)."""

    scenario: Scenario
    seed: int
    truth: trajectory.Truth  # internal rate (truth.substeps per IMU interval), from the start of the first interval
    imu_rate_hz: int
    imu_t: np.ndarray  # (n,) true run time of each IMU sampling instant
    ideal_dtheta: np.ndarray  # (n, 3) error-free increments
    ideal_dv: np.ndarray
    imu_dtheta: np.ndarray  # (n, 3) as the unit reports them (before quantisation)
    imu_dv: np.ndarray
    imu_errors: imu.ImuErrors
    gnss: gnss.GnssSim
    reference: reference.ReferenceData | None = None  # the dual-antenna RTK reference, if the scenario has one
    imu_i0: int = 0
    last: bool = True  # the run's last block

    @property
    def truth_at_imu(self) -> np.ndarray:
        """Indices of the internal truth samples at the IMU's sampling instants."""
        sub = self.truth.substeps
        return np.arange(sub, len(self.truth.t), sub)


class Simulator:
    """A scenario's run for one seed, made block by block in order."""

    def __init__(self, sc: Scenario, seed: int = 0):
        self.scenario, self.seed = sc, seed
        rng = np.random.default_rng([seed, 0x9E3779B9])
        # The IMU's own clock runs fast by imu_clock_ppm: its samples come that much more often.
        period = 1.0 / (sc.imu.rate_hz * (1.0 + 1e-6 * sc.timing.imu_clock_ppm))
        phase = float(rng.uniform(0.0, period))  # the IMU does not sample on GPS seconds
        self.n_imu = int((sc.duration_s - phase) / period)
        self.truth = trajectory.TruthStream(sc, phase + period, 1.0 / period, self.n_imu)
        off = sc.imu.seed_offset
        self.imu = imu.ImuErrorProcess(sc.imu, np.random.default_rng([seed, off]),
                                       lambda name: Stream((seed, off, zlib.crc32(name.encode())), width=3))
        self.receiver = gnss.Receiver(sc, seed)
        first = self.truth.times(0, 1)[0]
        self.reference = (reference.ReferenceStream(sc, sc.reference, seed, first, self.truth.t_end)
                          if sc.reference.enabled else None)

    def block_samples(self, block_s: float | None) -> int:
        """IMU samples per block: block_s rounded to whole integration spans (None: the whole run)."""
        if block_s is None:
            return max(1, self.n_imu)
        if not block_s > 0:
            raise ValueError(f"block length must be > 0 s, got {block_s}")
        span = self.truth.atom_samples
        return span * max(1, int(round(block_s * self.scenario.imu.rate_hz / span)))

    def blocks(self, block_s: float | None = DEFAULT_BLOCK_S) -> Iterator[Simulation]:
        """The run as consecutive blocks of about block_s seconds (None: one block)."""
        step = self.block_samples(block_s)
        sc = self.scenario
        for i0 in range(0, self.n_imu, step):
            i1 = min(i0 + step, self.n_imu)
            last = i1 == self.n_imu
            tr = self.truth.span(i1)
            dtheta, dv = trajectory.ideal_increments(tr)
            gd, ad = self.imu.drift(i1)
            mth, mdv = self.imu.measure(i0, dtheta, dv, gd, ad)
            c = self.imu.constants
            errors = imu.ImuErrors(c.gyro_bias_rad_per_s, c.accel_bias_mps2, c.gyro_matrix, c.accel_matrix, gd, ad,
                                   c.gyro_g_matrix)
            g = self.receiver.epochs(tr, last)
            ref = self.reference.epochs(tr, g, last) if self.reference is not None else None
            yield Simulation(sc, self.seed, tr, sc.imu.rate_hz, tr.t[tr.substeps::tr.substeps], dtheta, dv, mth, mdv,
                             errors, g, ref, i0, last)


def simulate(sc: Scenario, seed: int = 0) -> Simulation:
    """The whole run in memory (one block: the same values as any cut into blocks)."""
    return next(Simulator(sc, seed).blocks(None))


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


def tight_inputs(s: Simulation) -> dict:
    """The tightly coupled filter's GNSS inputs of a simulation, as filter.run's keywords: the
    pseudoranges, the ephemerides decoded from the broadcast subframes by the core's decoder (the
    receiver side, as a replay gets them), the broadcast ionosphere and the GPS time of t = 0."""
    from gpsins import _core  # only here: the simulator's own models never use the core

    from .ephemeris import encode_subframes

    week = s.scenario.start.gps_week
    ephs = [_core.gnss.decode_subframes(encode_subframes(e), e.prn, week) for e in s.gnss.ephemerides.values()]
    return dict(pseudoranges=pseudorange_table(s), ephemerides=ephs, klobuchar=(s.gnss.ion_alpha, s.gnss.ion_beta),
                gps_time_offset_s=week * SECONDS_PER_WEEK + s.scenario.start.gps_tow_s)


def pseudorange_table(s: Simulation) -> np.ndarray:
    """(k, 6) [t, prn, pseudorange, C/N0, lock count, Doppler Hz] per tracked satellite, t the receiver's
    time of the epoch on the run's time line (tow_rx - start tow)."""
    g = s.gnss
    k, j = np.nonzero(g.tracked)
    t = g.tow_rx[k] - s.scenario.start.gps_tow_s
    return np.column_stack([t, j + 1, g.pseudorange_m[k, j], g.cn0_dbhz[k, j], g.lock_count[k, j],
                            g.doppler_hz()[k, j]])
