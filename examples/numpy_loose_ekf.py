"""A loosely coupled GPS/INS filter in pure NumPy, written to be read: an example plug-in estimator.

    PYTHONPATH=examples gpsins replay SESSION --estimator numpy_loose_ekf:estimate

The replay hands ``estimate`` an ``EstimatorInputs`` (python/gpsins/estimator.py) and scores what it
returns exactly as it scores the built-in C++ filter. This one is deliberately plain:

- strapdown mechanisation in ECEF of the IMU's angle and velocity increments (first order: the Earth's
  rotation, Coriolis and a J2 + centrifugal normal-gravity model; no coning or sculling terms);
- a 15-state error-state extended Kalman filter: attitude, velocity, position, gyro bias, accel bias;
- coarse alignment: roll, pitch and the gyro bias from the still seconds at the start; the heading
  from the course over ground once the platform moves (a hand-held device, which need not point
  where it goes, from matching its velocity changes to the fixes' instead);
- position-fix updates (antenna lever arm, R from the fix's stated sigmas or UERE x DOP) behind a
  chi-square gate.

Left out, and what the built-in filter's better scores are made of: zero-velocity and fix-velocity
updates, states for the fixes' time-correlated errors, the vehicle constraint, IMU gap handling.

Conventions: ``C`` rotates body (forward-right-down) vectors into ECEF. Errors are truth minus
estimate: dv = v_true - v, dr = r_true - r, and the attitude error psi (ECEF axes) is the small
rotation with C_true = (I + [psi x]) C. The error state is x = [psi, dv, dr, dbg, dba] (15).
"""

from __future__ import annotations

import math

import numpy as np

OMEGA_IE = 7.292115e-5  # Earth rotation rate, rad/s
W_IE = np.array([0.0, 0.0, OMEGA_IE])
GM, J2 = 3.986004418e14, 1.082627e-3  # WGS84 gravitational constant (m^3/s^2) and J2
A_WGS84, E2_WGS84 = 6378137.0, 6.69437999014e-3  # semi-major axis (m), first eccentricity squared

LEVEL_BLOCK_S = 0.5  # the still test looks at half-second blocks
LEVEL_MAX_S = 10.0  # at most this much of the still stretch levels: a longer average blurs a wandering bias
STILL_MPS = 0.3  # the fixes show the platform at rest while slower than this (several sigma of their noise)
HEADING_SPEED_MPS = 2.0  # the course over ground gives the heading once the platform is this fast ...
MIN_COURSE_SPEED_MPS = 0.5  # ... or, if it never is, at the first fix this fast
ALIGN_S = 5.0  # hand-held: seconds of fixes whose velocity changes give the heading (ten 2 Hz strides)
MAX_REJECTIONS = 5  # a gate that refuses this many fixes in a row guards a filter that is lost: let one in

# For a configuration that states none: the figures of a consumer MEMS unit and a standalone receiver.
FALLBACK = {"gyro_arw_rad_per_sqrt_s": 1e-3, "accel_vrw_mps_per_sqrt_s": 1e-2, "gyro_rrw_rad_per_s_sqrt_s": 1e-5,
            "accel_rrw_mps2_per_sqrt_s": 1e-3, "gyro_bias_instability_rad_per_s": 0.0,
            "accel_bias_instability_mps2": 0.0, "bias_tau_s": 100.0, "accel_bias_residual_mps2": 0.05,
            "fix_uere_m": 3.0, "fix_uere_2d_m": 5.0, "heading_sigma_deg": 3.0, "velocity_sigma_mps": 0.5,
            "gate_probability": 0.9999, "fix_velocity_lag_s": 0.0}


# --- geometry ----------------------------------------------------------------------------------------

def skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def rotation(phi):
    """Rotation matrix of the rotation vector phi (Rodrigues' formula, exact at any angle)."""
    a = math.sqrt(phi @ phi)
    if a < 1e-12:
        return np.eye(3) + skew(phi)
    k = skew(phi / a)
    return np.eye(3) + math.sin(a) * k + (1.0 - math.cos(a)) * k @ k


def lat_lon(r):
    """Geodetic latitude and longitude (rad) of ECEF positions (n, 3): Bowring's formula, mm-exact near the ground."""
    r = np.atleast_2d(r)
    b = A_WGS84 * math.sqrt(1.0 - E2_WGS84)
    p = np.hypot(r[:, 0], r[:, 1])
    th = np.arctan2(r[:, 2] * A_WGS84, p * b)
    lat = np.arctan2(r[:, 2] + E2_WGS84 / (1 - E2_WGS84) * b * np.sin(th) ** 3,
                     p - E2_WGS84 * A_WGS84 * np.cos(th) ** 3)
    return lat, np.arctan2(r[:, 1], r[:, 0])


def ned_to_ecef(lat, lon):
    """(n, 3, 3) rotations NED -> ECEF: the columns are north, east and down in ECEF."""
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    return np.stack([np.stack([-sl * co, -so, -cl * co], -1), np.stack([-sl * so, co, -cl * so], -1),
                     np.stack([cl, np.zeros_like(lat), -sl], -1)], -2)


def gravity(r):
    """Gravity in ECEF: the J2 gravitation plus the centrifugal pull of the Earth's turning, which near
    the ground is normal gravity to a few parts in 1e5, well below what a MEMS accelerometer resolves."""
    rr = r @ r
    z2 = r[2] ** 2 / rr
    j2 = 1.5 * J2 * A_WGS84 ** 2 / rr * np.array([1 - 5 * z2, 1 - 5 * z2, 3 - 5 * z2])
    return -GM / rr ** 1.5 * r * (1 + j2) + OMEGA_IE ** 2 * np.array([r[0], r[1], 0.0])


def body_to_ned(yaw, pitch, roll):
    cy, sy, cp, sp, cr, sr = (math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch), math.cos(roll),
                              math.sin(roll))
    return np.array([[cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
                     [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy], [-sp, sr * cp, cr * cp]])


def quat_from_dcm(C):
    """Hamilton (w, x, y, z), w >= 0, of rotation matrices (n, 3, 3). The symmetric matrix 4 q q^T is
    written out of C; its row with the largest diagonal gives q without dividing by a small number."""
    d0, d1, d2 = C[:, 0, 0], C[:, 1, 1], C[:, 2, 2]
    s = lambda i, j, sign: C[:, i, j] + sign * C[:, j, i]  # noqa: E731
    rows = [[1 + d0 + d1 + d2, s(2, 1, -1), s(0, 2, -1), s(1, 0, -1)],
            [s(2, 1, -1), 1 + d0 - d1 - d2, s(0, 1, 1), s(0, 2, 1)],
            [s(0, 2, -1), s(0, 1, 1), 1 - d0 + d1 - d2, s(1, 2, 1)],
            [s(1, 0, -1), s(0, 2, 1), s(1, 2, 1), 1 - d0 - d1 + d2]]
    M = np.stack([np.stack(row, -1) for row in rows], -2)
    n, i = np.arange(len(C)), np.argmax(np.diagonal(M, axis1=1, axis2=2), axis=1)
    q = M[n, i] / (2.0 * np.sqrt(M[n, i, i]))[:, None]
    return q * np.where(q[:, :1] < 0, -1.0, 1.0)


def chi2_quantile(p, dof):
    """The chi-square quantile for 2 or 3 degrees of freedom, by bisection on the closed-form CDF."""
    cdf = {2: lambda x: 1.0 - math.exp(-x / 2),
           3: lambda x: math.erf(math.sqrt(x / 2)) - math.sqrt(2 * x / math.pi) * math.exp(-x / 2)}[dof]
    lo, hi = 0.0, 200.0
    for _ in range(60):
        lo, hi = ((lo + hi) / 2, hi) if cdf((lo + hi) / 2) < p else (lo, (lo + hi) / 2)
    return hi


# --- configuration -----------------------------------------------------------------------------------

def figure(cfg, key):
    """A figure as a 3-vector: from [imu_noise], else the top level, else the fallback."""
    v = (cfg.get("imu_noise") or {}).get(key, cfg.get(key))
    return np.broadcast_to(np.asarray(FALLBACK.get(key, 0.0) if v is None else v, float), (3,)).copy()


def noise_model(cfg):
    """Continuous-time noise densities per axis. White noise N has the density N^2. The biases are random
    walks driven by their rate random walk K and, for a bias instability B, by the 2 B^2 / tau that drives
    a Gauss-Markov process of sigma B and correlation time tau (its pull back to zero left out)."""
    tau = float(figure(cfg, "bias_tau_s")[0])
    return {"gyro": figure(cfg, "gyro_arw_rad_per_sqrt_s") ** 2, "accel": figure(cfg, "accel_vrw_mps_per_sqrt_s") ** 2,
            "gyro_bias": figure(cfg, "gyro_rrw_rad_per_s_sqrt_s") ** 2
            + 2 * figure(cfg, "gyro_bias_instability_rad_per_s") ** 2 / tau,
            "accel_bias": figure(cfg, "accel_rrw_mps2_per_sqrt_s") ** 2
            + 2 * figure(cfg, "accel_bias_instability_mps2") ** 2 / tau}


def calibrated(imu, cfg):
    """Times, steps and increments with the configured calibration taken out as the built-in filter does:
    (raw - bias dt) / (1 + scale factor). A data set without a calibration states zeros."""
    t = imu[:, 0]
    dt = np.diff(t, prepend=t[0] - np.median(np.diff(t)))
    cal = lambda k: figure(cfg, k)  # noqa: E731
    dth = (imu[:, 1:4] - cal("gyro_bias_cal_rad_per_s") * dt[:, None]) / (1 + cal("gyro_scale_factor_cal"))
    dv = (imu[:, 4:7] - cal("accel_bias_cal_mps2") * dt[:, None]) / (1 + cal("accel_scale_factor_cal"))
    return t, dt, dth, dv


def fix_sigmas(fix, cfg):
    """NED sigmas of a fix's position: those it states, else UERE x HDOP / VDOP; and how many axes to use
    (a 2-D fix's height is the receiver's assumption, not a measurement)."""
    two_d = fix[9] == 3
    stated = fix[10:13] if len(fix) >= 13 else np.full(3, np.nan)
    uere = float(figure(cfg, "fix_uere_2d_m" if two_d else "fix_uere_m")[0])
    return np.where(np.isfinite(stated) & (stated > 0), stated, uere * fix[[7, 7, 8]]), (2 if two_d else 3)


# --- alignment ---------------------------------------------------------------------------------------

def coarse_level(t, dt, dth, dv, noise, t_end):
    """Roll, pitch and gyro bias from the still seconds at the start, up to t_end (the fixes' last sight of
    the platform at rest). A block is still while the accelerometer's scatter stays within 4 times its
    white noise and neither sensor's block mean strays 4 sigma from the mean so far: a smooth pull-away
    or turn is quiet, but it moves the means. Returns the sample range used too."""
    f, w = dv / dt[:, None], dth / dt[:, None]
    sf, sw = np.sqrt(noise["accel"] / np.median(dt)), np.sqrt(noise["gyro"] / np.median(dt))  # per sample
    edges = np.searchsorted(t, np.arange(t[0], max(t_end, t[0] + 2 * LEVEL_BLOCK_S), LEVEL_BLOCK_S))
    a, b = edges[0], edges[1]
    for e0, e1 in zip(edges[1:-1], edges[2:]):
        m = math.sqrt(e1 - e0)
        if (np.any(np.std(f[e0:e1], axis=0) > 4 * sf) or np.any(np.abs(f[e0:e1].mean(0) - f[a:b].mean(0)) > 4 * sf / m)
                or np.any(np.abs(w[e0:e1].mean(0) - w[a:b].mean(0)) > 4 * sw / m)):
            break
        b = e1
    a = max(a, int(np.searchsorted(t, t[b - 1] - LEVEL_MAX_S)))  # the last seconds: the gyros carry less
    fm = f[a:b].mean(axis=0)  # at rest the accelerometers feel only the reaction to gravity, -g along down
    roll, pitch = math.atan2(-fm[1], -fm[2]), math.atan2(fm[0], math.hypot(fm[1], fm[2]))
    # At rest the gyros see their bias plus the Earth's rate (7e-5 rad/s: small beside a MEMS bias).
    return roll, pitch, w[a:b].mean(axis=0), a, b


def heading_turn(t, fixes, v_ned, window, v_level, lag):
    """Hand-held: the azimuth of the level frame. The IMU's velocity changes in it, turned by that angle,
    must be the fixes' (at the instant their velocity stands for, ``lag`` before the fix): a least-squares
    turn in closed form, and its sigma from the residual scatter."""
    a = np.diff(v_level[np.clip(np.searchsorted(t, fixes[window, 0] - lag), 0, len(v_level) - 1), :2], axis=0)
    b = np.diff(v_ned[window, :2], axis=0)
    turn = math.atan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a * b))
    resid = b - a @ np.array([[math.cos(turn), math.sin(turn)], [-math.sin(turn), math.cos(turn)]])
    return turn, math.sqrt(np.sum(resid ** 2) / max(2 * len(a) - 1, 1) / max(np.sum(a ** 2), 1e-12))


def align(t, dt, dth, dv, fixes, cfg, noise, lever, level):
    """The start: the IMU sample k0, the fix j it starts from, the navigation state there and P0."""
    roll, pitch, bg, la, lb = level
    v_ned = np.einsum("nji,nj->ni", ned_to_ecef(*lat_lon(fixes[:, 1:4])), fixes[:, 4:7])
    speed = np.hypot(v_ned[:, 0], v_ned[:, 1])
    fast = np.flatnonzero(speed > (HEADING_SPEED_MPS if np.any(speed > HEADING_SPEED_MPS) else MIN_COURSE_SPEED_MPS))
    if not len(fast):
        raise ValueError("numpy_loose_ekf: the fixes never show the platform moving, so it has no heading")
    j = int(fast[0])
    window = np.flatnonzero((fixes[:, 0] >= fixes[j, 0]) & (fixes[:, 0] <= fixes[j, 0] + ALIGN_S))
    handheld = cfg.get("platform") == "handheld" and len(window) >= 3  # (fewer: the course it is)
    if handheld:
        j = int(window[-1])
    k0 = int(np.searchsorted(t, fixes[j, 0]))  # the first IMU sample at or after fix j
    # Strapdown in a level frame of arbitrary azimuth (no Earth rate: 15 deg/h over these seconds), from
    # the levelled attitude at rest on to k0: its tilt for the start, its velocity for a hand-held heading.
    C_lb = C_level = body_to_ned(0.0, pitch, roll)
    v_l, v_level, C_int = np.zeros(3), np.zeros((k0 + 1, 3)), np.zeros((3, 3))
    g_l = np.array([0.0, 0.0, float(np.linalg.norm(gravity(fixes[j, 1:4])))])
    for k in range(lb, k0 + 1):
        a = dth[k] - bg * dt[k]
        v_l = v_l + C_lb @ (dv[k] + 0.5 * np.cross(a, dv[k])) + g_l * dt[k]
        C_lb = C_lb @ rotation(a)
        v_level[k], C_int = v_l, C_int + C_lb * dt[k]
    yaw_l = math.atan2(C_lb[1, 0], C_lb[0, 0])
    stated_v = fixes.shape[1] >= 16 and fixes[j, 13] > 0
    sv = float(fixes[j, 13]) if stated_v else float(figure(cfg, "velocity_sigma_mps")[0])
    if handheld:  # a device in the hand need not point where it goes
        turn, yaw_sigma = heading_turn(t, fixes, v_ned, window, v_level, float(figure(cfg, "fix_velocity_lag_s")[0]))
    else:  # a vehicle points along its course, known as well as the velocity's noise allows
        turn, yaw_sigma = math.atan2(v_ned[j, 1], v_ned[j, 0]) - yaw_l, math.atan2(sv, speed[j])
    yaw_sigma = max(yaw_sigma, math.radians(float(figure(cfg, "heading_sigma_deg")[0])))
    C_en, C_turn = ned_to_ecef(*lat_lon(fixes[j, 1:4]))[0], body_to_ned(turn, 0.0, 0.0)
    C = C_en @ C_turn @ C_lb
    v = fixes[j, 4:7].copy()
    r = fixes[j, 1:4] - C @ lever + v * (t[k0] - fixes[j, 0])  # the IMU point, carried on to t[k0]

    # P0. Velocity and position: as fix j states them. Gyro bias: as well as the still average knows it
    # (its white noise, the Earth's rate in it, its wander since); accelerometer bias: the configured
    # turn-on residual. Attitude: the heading's sigma about down; the tilt is the biases' doing, so it is
    # correlated with them: levelling takes an accelerometer bias b for the tilt -(down x C_nb b) / g
    # (C_nb as it was then), and a gyro bias error dbg tilts the frame by -integral(C_nb dt) dbg while the
    # gyros carry it. With those correlations the filter knows that tilt and bias, at first, cancel in
    # the horizontal.
    T_level, carried = t[lb - 1] - t[la] + np.median(dt), t[k0] - t[lb - 1]
    P_bg = np.diag(noise["gyro"] / T_level + OMEGA_IE ** 2 + noise["gyro_bias"] * (t[k0] - (t[la] + t[lb - 1]) / 2))
    P_ba = np.diag(figure(cfg, "accel_bias_residual_mps2") ** 2)
    horizontal = C_en @ np.diag([1.0, 1.0, 0.0]) @ C_en.T  # the tilt part of an ECEF rotation vector
    A_a = -C_en @ skew([0.0, 0.0, 1.0]) @ C_turn @ C_level / g_l[2]  # tilt per accelerometer bias
    A_g = -horizontal @ C_en @ C_turn @ C_int  # tilt per gyro bias error
    P = np.zeros((15, 15))
    P[0:3, 0:3] = (A_a @ P_ba @ A_a.T + A_g @ P_bg @ A_g.T + horizontal * np.max(noise["gyro"]) * carried
                   + C_en @ np.diag([0.0, 0.0, yaw_sigma ** 2]) @ C_en.T)
    P[0:3, 9:12], P[0:3, 12:15] = A_g @ P_bg, A_a @ P_ba
    P[9:12, 0:3], P[12:15, 0:3] = P[0:3, 9:12].T, P[0:3, 12:15].T
    P[3:6, 3:6] = np.eye(3) * sv ** 2
    P[6:9, 6:9] = C_en @ np.diag(fix_sigmas(fixes[j], cfg)[0] ** 2) @ C_en.T
    P[9:12, 9:12], P[12:15, 12:15] = P_bg, P_ba
    return k0, j, C, v, r, bg, P


# --- the filter --------------------------------------------------------------------------------------

def estimate(inputs):
    """The plug-in entry point: EstimatorInputs in; the solution at every IMU sample from the start on."""
    if inputs.mode != "loose":
        raise ValueError(f"numpy_loose_ekf: loosely coupled only (asked for --mode {inputs.mode})")
    cfg, lever = inputs.config, np.asarray(inputs.lever_arm_body_m, float)
    noise = noise_model(cfg)
    t, dt, dth, dv = calibrated(np.asarray(inputs.imu, float), cfg)
    fixes = np.array(inputs.fixes, float)
    fixes = fixes[np.isin(fixes[:, 9], (2, 3)) & np.isfinite(fixes[:, 1:4]).all(axis=1)]
    fixes = fixes[(fixes[:, 0] > t[0]) & (fixes[:, 0] <= t[-1])]
    if len(fixes) < 2:
        raise ValueError("numpy_loose_ekf: fewer than two usable fixes within the IMU's span")
    no_v = ~np.isfinite(fixes[:, 4:7]).all(axis=1)  # a receiver without velocities: the positions' rate
    fixes[no_v, 4:7] = np.gradient(fixes[:, 1:4], fixes[:, 0], axis=0)[no_v]

    moving = np.flatnonzero(np.linalg.norm(fixes[:, 4:7], axis=1) > STILL_MPS)
    t_still = fixes[max(moving[0] - 1, 0), 0] if len(moving) else t[-1]
    level = coarse_level(t, dt, dth, dv, noise, t_still)
    k0, j, C, v, r, bg, P = align(t, dt, dth, dv, fixes, cfg, noise, lever, level)
    ba = np.zeros(3)

    p_gate = float(figure(cfg, "gate_probability")[0])
    gates = {d: chi2_quantile(p_gate, d) if 0 < p_gate < 1 else math.inf for d in (2, 3)}
    n = len(t) - k0
    out = {"r": np.empty((n, 3)), "v": np.empty((n, 3)), "C": np.empty((n, 3, 3)), "P": np.empty((n, 9, 9)),
           "b": np.empty((n, 6))}
    updates = {k: [] for k in ("t", "kind", "dof", "nis", "gate", "accepted", "innovation", "innovation_sigma")}
    I15, W_x = np.eye(15), skew(W_IE)
    fi, rejected = j + 1, 0

    for k in range(k0, len(t)):
        if k > k0:
            # Strapdown: the body's rotation over the step, then the Earth's under it; the specific force
            # rotated by the attitude at the step's start turned through half the step's rotation.
            h = dt[k]
            a, u = dth[k] - bg * h, dv[k] - ba * h
            f_e = C @ (u + 0.5 * np.cross(a, u)) / h
            C = rotation(-W_IE * h) @ C @ rotation(a)
            v_new = v + (f_e + gravity(r) - 2 * W_x @ v) * h
            r, v = r + 0.5 * (v + v_new) * h, v_new
            # The errors' dynamics, linearised about the estimate (psi' = -[w_ie x] psi - C dbg,
            # dv' = -[f x] psi - 2 [w_ie x] dv + (dg/dr) dr - C dba, dr' = dv), one Euler step.
            rn = math.sqrt(r @ r)
            F = np.zeros((15, 15))
            F[0:3, 0:3], F[0:3, 9:12] = -W_x, -C
            F[3:6, 0:3], F[3:6, 3:6], F[3:6, 12:15] = -skew(f_e), -2 * W_x, -C
            F[3:6, 6:9] = -GM / rn ** 3 * (np.eye(3) - 3 * np.outer(r, r) / rn ** 2)
            F[6:9, 3:6] = np.eye(3)
            Phi = I15 + F * h
            Q = np.zeros((15, 15))  # the sensors' white noise enters along the body axes, rotated to ECEF
            Q[0:3, 0:3] = C @ np.diag(noise["gyro"]) @ C.T * h
            Q[3:6, 3:6] = C @ np.diag(noise["accel"]) @ C.T * h
            Q[9:12, 9:12], Q[12:15, 12:15] = np.diag(noise["gyro_bias"] * h), np.diag(noise["accel_bias"] * h)
            P = Phi @ P @ Phi.T + Q

        while fi < len(fixes) and fixes[fi, 0] <= t[k]:
            fix = fixes[fi]
            fi += 1
            # The antenna as predicted at the fix's instant (at most one IMU step back, along v). In NED,
            # where the fix's R is diagonal and a 2-D fix simply drops its height.
            C_ne = ned_to_ecef(*lat_lon(fix[1:4]))[0].T
            sig, dof = fix_sigmas(fix, cfg)
            H = np.zeros((3, 15))
            H[:, 0:3], H[:, 6:9] = -skew(C @ lever), np.eye(3)  # antenna = r + (I + [psi x]) C lever
            z = (C_ne @ (fix[1:4] - (r + C @ lever - v * (t[k] - fix[0]))))[:dof]
            H, R = (C_ne @ H)[:dof], np.diag(sig[:dof] ** 2)
            S = H @ P @ H.T + R
            d2 = float(z @ np.linalg.solve(S, z))
            accepted = d2 <= gates[dof] or rejected >= MAX_REJECTIONS
            for key, val in (("t", fix[0]), ("kind", 1 if dof == 3 else 2), ("dof", dof), ("nis", d2),
                             ("gate", gates[dof]), ("accepted", accepted),
                             ("innovation", np.r_[z, np.full(3 - dof, np.nan)]),
                             ("innovation_sigma", np.r_[np.sqrt(np.diag(S)), np.full(3 - dof, np.nan)])):
                updates[key].append(val)
            if not accepted:
                rejected += 1
                continue
            rejected = 0
            K = np.linalg.solve(S, H @ P).T  # P H^T S^-1 (S and P are symmetric)
            dx = K @ z
            A = I15 - K @ H
            P = A @ P @ A.T + K @ R @ K.T  # Joseph form: stays symmetric and positive definite
            # The estimated errors go into the state; the error state starts again from zero.
            C = rotation(dx[0:3]) @ C
            v, r, bg, ba = v + dx[3:6], r + dx[6:9], bg + dx[9:12], ba + dx[12:15]

        i = k - k0
        out["r"][i], out["v"][i], out["C"][i], out["P"][i], out["b"][i] = r, v, C, P[:9, :9], np.r_[bg, ba]

    # gpsins.nav.estimator takes the covariance in local axes: attitude error about north, east, down,
    # velocity and position in NED (it turns them into its own filter's axes for the NEES).
    m = len(t) - k0
    C_ne = np.swapaxes(ned_to_ecef(*lat_lon(out["r"])), 1, 2)
    T_ned = np.zeros((m, 9, 9))
    for b in range(3):
        T_ned[:, 3 * b:3 * b + 3, 3 * b:3 * b + 3] = C_ne
    cov_ned = T_ned @ out["P"] @ np.swapaxes(T_ned, 1, 2)
    u = len(updates["t"])
    table = {"t": np.array(updates["t"], float), "kind": np.array(updates["kind"], np.int32),
             "id": np.zeros(u, np.int32), "dof": np.array(updates["dof"], np.int32),
             "nis": np.array(updates["nis"], float), "gate": np.array(updates["gate"], float),
             "log_det_s": np.full(u, np.nan), "r_scale": np.ones(u), "accepted": np.array(updates["accepted"], bool),
             "guarded": np.zeros(u, bool), "innovation": np.array(updates["innovation"], float).reshape(u, 3),
             "innovation_sigma": np.array(updates["innovation_sigma"], float).reshape(u, 3)}
    return {"t": t[k0:], "r_ecef": out["r"], "v_ecef": out["v"], "q_eb": quat_from_dcm(out["C"]),
            "sigma": np.sqrt(np.diagonal(cov_ned, axis1=1, axis2=2)),
            "covariance": cov_ned,
            "gyro_bias": out["b"][:, :3], "accel_bias": out["b"][:, 3:], "updates": table}
