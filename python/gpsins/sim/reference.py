"""The reference system of the report's experiments (the FOI report, section 4.2): a
dual-antenna carrier-phase receiver (Javad HD2 with a base station) giving RTK
position and the heading and pitch of its antenna baseline.

Accuracies from the report's Tables 4.3 and 4.4: RTK position about 0.01 m 3D
RMS, heading 0.004 / L rad RMS and pitch (or roll) 0.008 / L rad RMS for a
baseline of L metres (L = 1.5 m: 0.15 deg and 0.31 deg). The baseline lies along
the body's forward axis (the pole along the vehicle), so it measures exactly the
yaw and pitch of the z-y-x Euler angles, whatever the roll. Errors are a slow
Gauss-Markov part (carrier-phase multipath and residual atmosphere change
slowly) plus white noise, half the variance each.

Outages: RTK needs 5 tracked satellites and the attitude 4 (the simulated
receiver's own tracking stands in for the reference's); the report's receiver
"was very sensitive to vibrations and accelerations resulting in severe
measurement outages": here it loses lock whenever the specific force departs
from 1 g by more than ``vibration_threshold_g`` or the body rate exceeds
``rate_threshold_deg_s``, plus Poisson outages while moving
(``moving_outage_rate_hz``, exponential lengths), and after any loss needs
``refix_s`` (RTK) and ``reattitude_s`` (attitude) of good conditions to come
back.

File: ``reference.csv`` beside the session (see ``gpsins.reference`` for the
layout and the reader).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import earth
from .draws import Stream
from .processes import gauss_markov

G0 = 9.80665


@dataclass
class ReferenceModel:
    enabled: bool = True
    rate_hz: int = 10
    baseline_m: float = 1.5
    rtk_3d_rms_m: float = 0.01
    heading_rms_rad_times_m: float = 0.004  # Table 4.4: 0.004 / L rad
    pitch_rms_rad_times_m: float = 0.008  # Table 4.4: 0.008 / L rad
    correlation_s: float = 30.0  # of the slow half of the error
    min_sats_rtk: int = 5
    min_sats_attitude: int = 4
    vibration_threshold_g: float = 0.6
    rate_threshold_deg_s: float = 60.0
    moving_outage_rate_hz: float = 1.0 / 60.0
    moving_outage_mean_s: float = 8.0
    refix_s: float = 10.0
    reattitude_s: float = 3.0
    seed_offset: int = 5


@dataclass
class ReferenceData:
    t: np.ndarray  # (n,) run time (true GPS time - start)
    r_ecef: np.ndarray  # (n, 3) reported IMU-point position, NaN in outages
    heading_rad: np.ndarray  # (n,) NaN in outages
    pitch_rad: np.ndarray
    sigma_ned_m: np.ndarray  # (n, 3) the reported 1-sigma of position
    sigma_heading_rad: float
    sigma_pitch_rad: float
    position_ok: np.ndarray  # (n,) bool
    attitude_ok: np.ndarray


class ReferenceStream:
    """Reference epochs on whole multiples of 1 / rate_hz of GPS time over the truth grid
    [t_first, t_end], a truth block at a time: the draws are addressed by epoch and the outage
    and error processes carry their state, so the epochs are the same however the run is cut."""

    def __init__(self, sc, model: ReferenceModel, seed: int, t_first: float, t_end: float):
        self.sc, self.model = sc, model
        self.dt = dt = 1.0 / model.rate_hz
        self.first = np.ceil((sc.start.gps_tow_s + t_first) / dt) * dt - sc.start.gps_tow_s
        self.count = int((t_end - self.first) / dt) + 1
        s_axis = model.rtk_3d_rms_m / np.sqrt(3.0)
        self.s_axis, self.s_h, self.s_p = s_axis, model.heading_rms_rad_times_m / model.baseline_m, \
            model.pitch_rms_rad_times_m / model.baseline_m
        self.sigma = np.sqrt(0.5) * np.array([s_axis, s_axis, s_axis, self.s_h, self.s_p])  # half slow, half white
        key = (seed, model.seed_offset)
        self.draw = {name: Stream(key + (j,), kind, w) for j, (name, kind, w) in enumerate(
            (("outage start", "uniform", None), ("outage length", "exponential", None), ("slow", "normal", 5),
             ("white", "normal", 5)), start=1)}
        self.phi = np.exp(-dt / model.correlation_s)
        self._slow = np.random.default_rng([*key, 0]).standard_normal(5) * self.sigma  # stationary start
        self.next = 0
        self._outage_end = 0  # random outage covers epochs before this index
        self._last_lost = np.array([-10 ** 9, -10 ** 9])  # last epoch without RTK, without attitude
        self._gnss = (-np.inf, 0)  # (t, tracked satellites) of the latest receiver epoch seen

    def epochs(self, tr, g, last: bool) -> ReferenceData:
        """The epochs before the end of truth block `tr` (to its end if last), with the receiver's epochs
        `g` of the same block standing in for the reference's tracking."""
        model, dt, j0 = self.model, self.dt, self.next
        j1 = self.count if last else min(self.count, max(j0, int(np.ceil((tr.t[-1] - self.first) / dt)) + 1))
        t = self.first + dt * np.arange(j0, j1)
        if not last:
            t = t[t < tr.t[-1]]
        n = len(t)
        j1 = j0 + n
        self.next = j1
        idx = np.arange(j0, j1)
        k = np.clip(np.searchsorted(tr.t, t), 0, len(tr.t) - 1)  # conditions: the nearest grid point will do
        # Satellites tracked by the (stand-in) receiver at its latest epoch (the first one before it starts).
        g_t = np.concatenate([[self._gnss[0]], g.t])
        g_sats = np.concatenate([[self._gnss[1]], g.tracked.sum(axis=1)])
        e = np.searchsorted(g_t, t, side="right") - 1
        if self._gnss[0] == -np.inf:  # before the receiver's first epoch: its first
            e = np.maximum(e, 1)
        sats = g_sats[e]
        self._gnss = (float(g_t[-1]), int(g_sats[-1]))
        f_dev_g = np.abs(np.linalg.norm(tr.f_body[k], axis=1) - G0) / G0
        rate = np.degrees(np.linalg.norm(tr.w_ib_body[k], axis=1))
        speed = np.linalg.norm(tr.v_ned[k], axis=1)
        shaken = (f_dev_g > model.vibration_threshold_g) | (rate > model.rate_threshold_deg_s)
        # Random outages while moving: exponential lengths, possibly running into later blocks.
        starts = (speed > 0.5) & (self.draw["outage start"].rows(j0, j1) < model.moving_outage_rate_hz * dt)
        length = np.ceil(self.draw["outage length"].rows(j0, j1) * model.moving_outage_mean_s / dt).astype(np.int64)
        ends = np.where(starts, idx + length, 0)
        reach = np.maximum.accumulate(np.concatenate([[self._outage_end], ends]))
        random_out = (idx < reach[:-1]) | (starts & (length > 0))
        self._outage_end = int(reach[-1])
        lost = shaken | random_out
        pos_ok = ~self._hold_off(0, lost | (sats < model.min_sats_rtk), idx, int(round(model.refix_s / dt)))
        att_ok = ~self._hold_off(1, lost | (sats < model.min_sats_attitude), idx, int(round(model.reattitude_s / dt)))
        # Errors: half the variance slow (Gauss-Markov), half white.
        drive = self.draw["slow"].rows(j0, j1) * self.sigma * np.sqrt(1.0 - self.phi ** 2)
        slow = gauss_markov(self._slow, drive[1:], self.phi, include_first=True) if j0 == 0 and n \
            else gauss_markov(self._slow, drive, self.phi) if n else np.zeros((0, 5))
        if n:
            self._slow = slow[-1]
        err = slow + self.draw["white"].rows(j0, j1) * self.sigma
        # Truth at the epochs themselves (a 1 ms grid step is 17 mm and 0.2 deg on a roller coaster).
        c_en = earth.ecef_to_ned_matrix(tr.lat[k], tr.lon[k])
        r = tr.position_at(t) + np.einsum("nij,nj->ni", c_en, err[:, :3])
        i = np.clip(np.searchsorted(tr.t, t, side="right") - 1, 0, len(tr.t) - 2)
        w = (t - tr.t[i]) / (tr.t[i + 1] - tr.t[i])
        y0 = tr.ypr[i, 0]
        yaw = y0 + w * (np.mod(tr.ypr[i + 1, 0] - y0 + np.pi, 2 * np.pi) - np.pi)  # across +-pi the short way
        heading = np.mod(yaw + err[:, 3] + np.pi, 2 * np.pi) - np.pi
        pitch = tr.ypr[i, 1] + w * (tr.ypr[i + 1, 1] - tr.ypr[i, 1]) + err[:, 4]
        r[~pos_ok] = np.nan
        heading[~att_ok] = np.nan
        pitch[~att_ok] = np.nan
        return ReferenceData(t, r, heading, pitch, np.tile([self.s_axis] * 3, (n, 1)), self.s_h, self.s_p,
                             pos_ok, att_ok)

    def _hold_off(self, which: int, bad: np.ndarray, idx: np.ndarray, n_steps: int) -> np.ndarray:
        """True where the last bad epoch is fewer than n_steps epochs back (and where bad)."""
        last = np.maximum.accumulate(np.concatenate([[self._last_lost[which]], np.where(bad, idx, -10 ** 9)]))
        self._last_lost[which] = last[-1]
        return idx - last[1:] < n_steps


def concatenate(parts: list[ReferenceData]) -> ReferenceData:
    cat = lambda name: np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
    return ReferenceData(cat("t"), cat("r_ecef"), cat("heading_rad"), cat("pitch_rad"), cat("sigma_ned_m"),
                         parts[0].sigma_heading_rad, parts[0].sigma_pitch_rad, cat("position_ok"),
                         cat("attitude_ok"))
