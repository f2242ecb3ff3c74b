"""The non-holonomic constraint's noise from the recording: how often to apply it and how far a
car's lateral and vertical velocity really stray from zero.

The constraint (no lateral, no vertical velocity of the vehicle) is never exact. The vertical row
suffers most: the body pitches on its springs at 1-2 Hz, so the body's own vertical velocity is
the speed times that pitch, an oscillation of a tenth of a metre per second or more at road speed
that averages to nothing over a second. Applied every tenth of a second as white noise of a
declared sigma, such an error is followed: the filter's pitch is shaken at the ride's frequency and
an outage starts with the pitch a tenth of a degree off, which gravity turns into metres of
along-track drift within 15 s.

So the error is measured on the recording, with the mounting already found:

1. a first pass with the constraint at its configured interval (gate off, so every update counts):
   the vertical innovations' autocorrelation over lags of one interval and more, and the first
   lag at which it is no longer positive, the spacing at which one update's error no longer
   predicts the next's. The constraint is applied at that spacing (capped at MAX_INTERVAL_S);
2. a second pass at that spacing: each row's variance from its innovations by covariance
   matching (Mehra 1970): E[nu^2] = H P H' + R, so R = mean(nu^2) - mean(S - R_used), never
   below MIN_SIGMA_MPS.

The lateral row's innovations on a car that does not skid are the filter's own heading error seen
through the speed (correlated over many seconds), and matching makes its sigma small; the floor
keeps it from claiming more than the constraint can hold.
"""

from __future__ import annotations

import numpy as np

from . import runs as flt

NONHOLONOMIC = 7  # the update kind (gpsins._core.UPDATE_KINDS)
MAX_INTERVAL_S = 1.0
MAX_LAGS = 20
# No wheeled vehicle holds its lateral or vertical velocity to better than a centimetre per second
# (tyre slip, the road's texture): the floor for either row's sigma.
MIN_SIGMA_MPS = 0.01
MIN_UPDATES = 200


def _rows(updates: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The constraint's update times, innovations and innovation sigmas (lateral, vertical columns)."""
    sel = np.asarray(updates["kind"]) == NONHOLONOMIC
    nu = np.asarray(updates["innovation"])[sel][:, :2]
    s = np.asarray(updates["innovation_sigma"])[sel][:, :2]
    return np.asarray(updates["t"])[sel], nu, s


def decorrelation_lag(x: np.ndarray, max_lag: int = MAX_LAGS) -> int:
    """The first lag (>= 1) at which the sequence's autocorrelation is no longer positive; max_lag when
    it stays positive."""
    c = np.asarray(x, float) - np.mean(x)
    den = float(np.dot(c, c))
    if den <= 0.0:
        return 1
    for k in range(1, min(max_lag, len(c) - 1) + 1):
        if float(np.dot(c[:-k], c[k:])) / den <= 0.0:
            return k
    return max_lag


def _sigmas(cfg: dict) -> np.ndarray:
    lateral = float(cfg.get("nhc_sigma_mps", 0.1))
    vertical = float(cfg.get("nhc_vertical_sigma_mps", 0.0))
    return np.array([lateral, vertical if vertical > 0.0 else lateral])


def fit_constraint(imu, fixes: np.ndarray, cfg: dict) -> tuple[dict, dict | None]:
    """The configuration with the constraint's interval and per-row sigmas measured on the recording
    (module doc), and what was found; unchanged (None) when the drive gives too few updates."""
    base = dict(cfg, gate_probability=0.0, gnss_reset_timeout_s=0.0, nonholonomic_constraint=True)
    t, nu, _ = _rows(flt.run(imu, fixes, base, mode="loose", output_every=10 ** 9).updates)
    if len(t) < MIN_UPDATES:
        return cfg, None
    spacing = float(np.median(np.diff(t)))
    lag = decorrelation_lag(nu[:, 1])
    interval = min(MAX_INTERVAL_S, lag * spacing)
    # The next update comes the first IMU sample at or after the interval: ask for a little less.
    at = dict(base, nhc_interval_s=interval - 0.5 * spacing / max(lag, 1))
    t2, nu2, s2 = _rows(flt.run(imu, fixes, at, mode="loose", output_every=10 ** 9).updates)
    if len(t2) < MIN_UPDATES // max(lag, 1):
        return cfg, None
    used = _sigmas(at)
    r = np.mean(nu2 ** 2, axis=0) - np.mean(s2 ** 2 - used ** 2, axis=0)
    sigma = np.sqrt(np.maximum(r, MIN_SIGMA_MPS ** 2))
    out = dict(cfg, nhc_interval_s=at["nhc_interval_s"], nhc_sigma_mps=float(sigma[0]),
               nhc_vertical_sigma_mps=float(sigma[1]))
    return out, {"interval_s": float(np.median(np.diff(t2))), "lateral_sigma_mps": float(sigma[0]),
                 "vertical_sigma_mps": float(sigma[1]), "vertical_decorrelation_lag": lag,
                 "updates": int(len(t2))}
