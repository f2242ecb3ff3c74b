"""The reference system of the report's experiments (seed 004 section 4.2): a
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


def _gauss_markov(rng, n, dt, tau, sigma):
    """(n, k) first-order Gauss-Markov of stationary std sigma (per column)."""
    sigma = np.atleast_1d(np.asarray(sigma, dtype=np.float64))
    a = np.exp(-dt / tau)
    w = rng.standard_normal((n, len(sigma))) * sigma * np.sqrt(1.0 - a * a)
    out = np.empty_like(w)
    out[0] = rng.standard_normal(len(sigma)) * sigma
    for k in range(1, n):
        out[k] = a * out[k - 1] + w[k]
    return out


def _hold_off(bad: np.ndarray, n_steps: int) -> np.ndarray:
    """True where the last bad sample is fewer than n_steps samples back (and where bad)."""
    out = bad.copy()
    last = -10 ** 9
    for k in range(len(bad)):
        if bad[k]:
            last = k
        elif k - last < n_steps:
            out[k] = True
    return out


def simulate(sim, model: ReferenceModel, rng: np.random.Generator) -> ReferenceData:
    """Reference epochs on whole multiples of 1 / rate_hz of GPS time over the run."""
    sc, tr = sim.scenario, sim.truth
    dt = 1.0 / model.rate_hz
    first = np.ceil((sc.start.gps_tow_s + tr.t[0]) / dt) * dt - sc.start.gps_tow_s
    t = first + dt * np.arange(int((tr.t[-1] - first) / dt) + 1)
    k = np.clip(np.searchsorted(tr.t, t), 0, len(tr.t) - 1)  # conditions: the nearest grid point will do
    n = len(t)
    # Conditions: satellites tracked by the (stand-in) receiver at the latest epoch, dynamics.
    g = sim.gnss
    epoch = np.clip(np.searchsorted(g.t, t, side="right") - 1, 0, len(g.t) - 1)
    sats = g.tracked[epoch].sum(axis=1)
    f_dev_g = np.abs(np.linalg.norm(tr.f_body[k], axis=1) - G0) / G0
    rate = np.degrees(np.linalg.norm(tr.w_ib_body[k], axis=1))
    speed = np.linalg.norm(tr.v_ned[k], axis=1)
    shaken = (f_dev_g > model.vibration_threshold_g) | (rate > model.rate_threshold_deg_s)
    random_out = np.zeros(n, dtype=bool)
    moving = speed > 0.5
    starts = moving & (rng.random(n) < model.moving_outage_rate_hz * dt)
    for i in np.flatnonzero(starts):
        random_out[i:i + int(np.ceil(rng.exponential(model.moving_outage_mean_s) / dt))] = True
    lost = shaken | random_out
    pos_ok = ~_hold_off(lost | (sats < model.min_sats_rtk), int(round(model.refix_s / dt)))
    att_ok = ~_hold_off(lost | (sats < model.min_sats_attitude), int(round(model.reattitude_s / dt)))
    # Errors: half the variance slow (Gauss-Markov), half white.
    s_axis = model.rtk_3d_rms_m / np.sqrt(3.0)
    s_h = model.heading_rms_rad_times_m / model.baseline_m
    s_p = model.pitch_rms_rad_times_m / model.baseline_m
    half = np.sqrt(0.5)
    slow = _gauss_markov(rng, n, dt, model.correlation_s, half * np.array([s_axis, s_axis, s_axis, s_h, s_p]))
    white = rng.standard_normal((n, 5)) * half * np.array([s_axis, s_axis, s_axis, s_h, s_p])
    err = slow + white
    # Truth at the epochs themselves (a 1 ms grid step is 17 mm and 0.2 deg on a roller coaster).
    c_en = earth.ecef_to_ned_matrix(tr.lat[k], tr.lon[k])
    r = tr.position_at(t) + np.einsum("nij,nj->ni", c_en, err[:, :3])
    yaw = np.interp(t, tr.t, np.unwrap(tr.ypr[:, 0]))
    heading = np.mod(yaw + err[:, 3] + np.pi, 2 * np.pi) - np.pi
    pitch = np.interp(t, tr.t, tr.ypr[:, 1]) + err[:, 4]
    r[~pos_ok] = np.nan
    heading[~att_ok] = np.nan
    pitch[~att_ok] = np.nan
    return ReferenceData(t, r, heading, pitch, np.tile([s_axis, s_axis, s_axis], (n, 1)), s_h, s_p, pos_ok, att_ok)
