"""Truth trajectory at a high internal rate, and the ideal IMU increments.

Speed, heading, grade and roll are smooth analytic functions of time (quintic
ramps per segment; roll from banking targets plus, where a segment asks for it,
the bank of a coordinated turn, atan(v psi' cos(theta) / g0)), so velocity in
NED and its derivative are exact. A scenario with a [track] (a ride along a 3-D
curve, sim/track.py) takes speed and the three angles from the track instead. Latitude
and longitude follow from the curvature ODE (Simpson's rule on half steps,
iterated to a fixed point); height is the exact integral of the vertical
speed. Everything else is evaluated in closed form: ECEF acceleration from
the NED derivative and the transport rate, specific force from J2 gravity
with the centrifugal and Coriolis terms, body rate from Earth rate, transport
rate and Euler rates.

The ideal increments are exact at the IMU's sampling instants: delta-theta is
the rotation vector of the body's inertial attitude change over the interval
(coning included), delta-v the integral of specific force taken in inertial
space and expressed in the start-of-interval body frame (sculling included),
by composite Simpson over the internal samples of the interval.

The internal grid is an even number of steps per IMU interval chosen so the
internal rate stays near 1 kHz whatever the IMU's rate (16 steps at 64 Hz,
10 at 100 Hz, 6 at 200 Hz, 2 at 400 Hz): the IMU's sampling instants are
always grid points, and the cost per second of drive hardly depends on the rate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import earth
from .ride import ride
from .scenario import Scenario

INTERNAL_RATE_HZ = 1024.0  # target rate of the internal grid


def substeps_for(imu_rate_hz: float) -> int:
    """Internal steps per IMU interval: even (composite Simpson), at least 2, rate near 1 kHz."""
    if not imu_rate_hz > 0:
        raise ValueError(f"IMU rate must be > 0 Hz, got {imu_rate_hz}")
    return max(2, 2 * int(round(INTERNAL_RATE_HZ / (2.0 * imu_rate_hz))))


G0 = 9.80665  # the bank of a coordinated turn is taken at standard gravity


def _smoothstep(tau):
    return tau ** 3 * (10.0 - 15.0 * tau + 6.0 * tau * tau), 30.0 * tau ** 2 * (1.0 - tau) ** 2


def _smoothstep_dd(tau):
    return 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau)


@dataclass
class Profiles:
    speed: np.ndarray
    speed_dot: np.ndarray
    yaw: np.ndarray
    yaw_dot: np.ndarray
    pitch: np.ndarray
    pitch_dot: np.ndarray
    roll: np.ndarray
    roll_dot: np.ndarray


@dataclass
class SegmentTable:
    """Per segment: start time, duration, (start, target) of speed, yaw, pitch, bank, coordinated flag."""

    t0: np.ndarray
    dur: np.ndarray
    ends: np.ndarray  # (n, 2, 4)
    coordinated: np.ndarray


def segment_table(sc: Scenario) -> SegmentTable:
    n_seg = len(sc.segments)
    t0, dur = np.empty(n_seg), np.empty(n_seg)
    ends = np.empty((n_seg, 2, 4))
    coordinated = np.array([bool(seg.coordinated) for seg in sc.segments])
    s0, y0, p0, r0, a = 0.0, np.radians(sc.start.heading_deg), 0.0, 0.0, 0.0
    for k, seg in enumerate(sc.segments):
        s1 = s0 if seg.speed_mps is None else float(seg.speed_mps)
        y1 = y0 + np.radians(seg.turn_deg)
        p1 = p0 if seg.grade_deg is None else np.radians(seg.grade_deg)
        r1 = r0 if seg.bank_deg is None else np.radians(seg.bank_deg)
        t0[k], dur[k], ends[k] = a, seg.duration_s, ((s0, y0, p0, r0), (s1, y1, p1, r1))
        s0, y0, p0, r0, a = s1, y1, p1, r1, a + seg.duration_s
    return SegmentTable(t0, dur, ends, coordinated)


def profiles(sc: Scenario, t: np.ndarray, table: SegmentTable | None = None) -> Profiles:
    """Speed, yaw (heading), pitch (grade) and roll with their time derivatives at times t
    (``table``: the scenario's segment_table, made once by callers that come back often)."""
    t = np.asarray(t, dtype=np.float64)
    if sc.track is not None:
        k = sc.track.kinematics(t - sc.track.spec.rest_before_s)
        return Profiles(k["speed"], k["speed_dot"], k["yaw"], k["yaw_dot"], k["pitch"], k["pitch_dot"],
                        k["roll"], k["roll_dot"])
    tb = segment_table(sc) if table is None else table
    t0, dur, ends, coordinated, n_seg = tb.t0, tb.dur, tb.ends, tb.coordinated, len(tb.t0)
    # Each time's segment: the one it starts in; past the end, the last one (held at its target).
    k = np.minimum(np.searchsorted(t0 + dur, t, side="right"), n_seg - 1)
    tau = np.clip((t - t0[k]) / dur[k], 0.0, 1.0)
    s, ds = _smoothstep(tau)
    moving, d = tau < 1.0, dur[k]
    out = []
    for j in range(4):
        a, b = ends[k, 0, j], ends[k, 1, j]
        out += [a + (b - a) * s, (b - a) * ds / d * moving]
    yaw_ddot = (ends[k, 1, 1] - ends[k, 0, 1]) * _smoothstep_dd(tau) / d ** 2 * moving
    before = t < 0.0
    if np.any(before):  # before the run: standing as at the start
        for x in out:
            x[before] = 0.0
        out[2][before] = np.radians(sc.start.heading_deg)
        yaw_ddot[before] = 0.0
    c = coordinated[k] & moving & ~before
    if np.any(c):  # the bank of a coordinated turn, on top of the segment's banking
        v, vd, yd, pitch, pd = out[0][c], out[1][c], out[3][c], out[4][c], out[5][c]
        x = v * yd * np.cos(pitch) / G0
        xd = (vd * yd * np.cos(pitch) + v * yaw_ddot[c] * np.cos(pitch) - v * yd * np.sin(pitch) * pd) / G0
        out[6][c] += np.arctan(x)
        out[7][c] += xd / (1.0 + x * x)
    return Profiles(*out)


def _ned_velocity(p: Profiles) -> tuple[np.ndarray, np.ndarray]:
    cy, sy, cp, sp = np.cos(p.yaw), np.sin(p.yaw), np.cos(p.pitch), np.sin(p.pitch)
    v = p.speed[:, None] * np.stack([cp * cy, cp * sy, -sp], -1)
    dv = (p.speed_dot[:, None] * np.stack([cp * cy, cp * sy, -sp], -1)
          + p.speed[:, None] * np.stack([-sp * cy * p.pitch_dot - cp * sy * p.yaw_dot,
                                         -sp * sy * p.pitch_dot + cp * cy * p.yaw_dot, -cp * p.pitch_dot], -1))
    return v, dv


@dataclass
class Truth:
    t: np.ndarray  # (n,) seconds from the run's start (true GPS time - start)
    lat: np.ndarray
    lon: np.ndarray
    h: np.ndarray
    r_ecef: np.ndarray  # (n, 3)
    v_ecef: np.ndarray
    v_ned: np.ndarray
    a_ecef: np.ndarray
    q_eb: np.ndarray  # (n, 4) Hamilton, body -> ECEF
    ypr: np.ndarray  # (n, 3) yaw, pitch, roll, rad
    f_body: np.ndarray  # specific force, m/s^2
    w_ib_body: np.ndarray  # inertial angular rate, rad/s
    c_eb: np.ndarray  # (n, 3, 3)
    substeps: int  # internal steps per IMU interval
    step: float | None = None  # the grid's nominal step, s (the same for every block of a run)

    def __len__(self) -> int:
        return len(self.t)

    def position_at(self, tq: np.ndarray) -> np.ndarray:
        """ECEF position at arbitrary times, cubic Hermite (position and velocity) between samples."""
        return _hermite(self.t, self.r_ecef, self.v_ecef, np.asarray(tq, dtype=np.float64))

    def velocity_at(self, tq: np.ndarray) -> np.ndarray:
        return _hermite(self.t, self.v_ecef, self.a_ecef, np.asarray(tq, dtype=np.float64))


def _hermite(t, x, dx, tq):
    i = np.clip(np.searchsorted(t, tq, side="right") - 1, 0, len(t) - 2)
    h = t[i + 1] - t[i]
    s = ((tq - t[i]) / h)[..., None]
    h = h[..., None]
    h00, h10, h01, h11 = 2 * s ** 3 - 3 * s ** 2 + 1, s ** 3 - 2 * s ** 2 + s, -2 * s ** 3 + 3 * s ** 2, s ** 3 - s ** 2
    return h00 * x[i] + h10 * h * dx[i] + h01 * x[i + 1] + h11 * h * dx[i + 1]


def _integrate_position(t: np.ndarray, v: np.ndarray, vm: np.ndarray, lat0: float, lon0: float, h0: float):
    """lat, lon, h at grid times t from (lat0, lon0, h0) at t[0], given NED velocity on the grid (v)
    and at half steps (vm)."""
    dt = np.diff(t)

    def cumulative(f, fm):
        return np.concatenate(([0.0], np.cumsum(dt / 6.0 * (f[:-1] + 4.0 * fm + f[1:]))))

    h = h0 + cumulative(-v[:, 2], -vm[:, 2])
    hm = 0.5 * (h[:-1] + h[1:]) + dt / 8.0 * (-v[:-1, 2] + v[1:, 2])
    lat = np.full_like(t, lat0)
    for _ in range(6):
        m, _n = earth.radii(lat)
        dlat = v[:, 0] / (m + h)
        latm = 0.5 * (lat[:-1] + lat[1:]) + dt / 8.0 * (dlat[:-1] - dlat[1:])
        mm, _ = earth.radii(latm)
        new = lat0 + cumulative(dlat, vm[:, 0] / (mm + hm))
        done = np.max(np.abs(new - lat)) < 1e-15
        lat = new
        if done:
            break
    m, n = earth.radii(lat)
    dlat = v[:, 0] / (m + h)
    latm = 0.5 * (lat[:-1] + lat[1:]) + dt / 8.0 * (dlat[:-1] - dlat[1:])
    _, nm = earth.radii(latm)
    dlon = v[:, 1] / ((n + h) * np.cos(lat))
    lon = lon0 + cumulative(dlon, vm[:, 1] / ((nm + hm) * np.cos(latm)))
    return lat, lon, h, dlat, dlon


CHUNK = 1 << 16  # grid points per pass of the pointwise stages (bounds their temporaries)


ATOM_STEPS = 8192  # grid steps (about) per integration span: the position ODE restarts from its end state


class TruthStream:
    """The truth grid made span by span, in order, in bounded memory.

    The position ODE is integrated over fixed spans of ``atom_samples`` IMU intervals, each
    from the end state of the one before, so the grid is the same however the run is cut into
    blocks, as long as every block but the last ends on a span boundary. Everything else is
    pointwise."""

    def __init__(self, sc: Scenario, t_first_sample: float, imu_rate_hz: float, n_samples: int,
                 substeps: int | None = None):
        self.sc = sc
        self.substeps = substeps_for(imu_rate_hz) if substeps is None else int(substeps)
        if self.substeps < 2 or self.substeps % 2:
            raise ValueError(f"substeps must be even and >= 2, got {self.substeps}")
        self.n_samples = int(n_samples)
        self.step = 1.0 / (imu_rate_hz * self.substeps)
        self.t0 = t_first_sample - 1.0 / imu_rate_hz
        self.atom_samples = max(1, ATOM_STEPS // self.substeps)
        self.table = segment_table(sc) if sc.track is None else None
        self._next = 0  # the next block's first sample interval
        self._llh = (np.radians(sc.start.lat_deg), np.radians(sc.start.lon_deg), float(sc.start.height_m))

    def times(self, j0: int, j1: int) -> np.ndarray:
        """Grid times of points j0..j1-1 (the same values whatever the block)."""
        return self.t0 + self.step * np.arange(j0, j1)

    @property
    def t_end(self) -> float:
        return float(self.times(self.n_samples * self.substeps, self.n_samples * self.substeps + 1)[0])

    def span(self, i1: int) -> Truth:
        """Truth from the end of the last span (sample interval ``self._next``) to the end of interval i1:
        grid points i0 * substeps .. i1 * substeps, both ends included."""
        i0, sub = self._next, self.substeps
        if not i0 < i1 <= self.n_samples or (i1 < self.n_samples and i1 % self.atom_samples):
            raise ValueError(f"a block must end on a span of {self.atom_samples} samples or at the run's end "
                             f"({self.n_samples}); asked for {i0}..{i1}")
        t = self.times(i0 * sub, i1 * sub + 1)
        v, _ = _ned_velocity(profiles(self.sc, t, self.table))
        vm, _ = _ned_velocity(profiles(self.sc, t[:-1] + 0.5 * self.step, self.table))
        n = len(t)
        lat, lon, h, dlat, dlon = (np.empty(n) for _ in range(5))
        lat[0], lon[0], h[0] = self._llh
        for a in range(0, n - 1, self.atom_samples * sub):
            b = min(a + self.atom_samples * sub, n - 1)
            k = slice(a, b + 1)
            lat[k], lon[k], h[k], dlat[k], dlon[k] = _integrate_position(t[k], v[k], vm[a:b], lat[a], lon[a], h[a])
        del vm
        self._llh, self._next = (lat[-1], lon[-1], h[-1]), i1
        out = Truth(t, lat, lon, h, np.empty((n, 3)), np.empty((n, 3)), v, np.empty((n, 3)), np.empty((n, 4)),
                    np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3, 3)), sub, self.step)
        # Everything else is pointwise: in chunks, so the temporaries stay small.
        for a in range(0, n, CHUNK):
            _pointwise(self.sc, out, dlat[a:a + CHUNK], dlon[a:a + CHUNK], slice(a, a + CHUNK), self.table)
        return out


def truth(sc: Scenario, t_first_sample: float, imu_rate_hz: float, n_samples: int,
          substeps: int | None = None) -> Truth:
    """Truth on the internal grid: `substeps` points per IMU interval (default: substeps_for the
    rate), from t_first_sample - 1/rate; the IMU's sampling instants are every substeps-th point."""
    return TruthStream(sc, t_first_sample, imu_rate_hz, n_samples, substeps).span(n_samples)


def _pointwise(sc: Scenario, out: Truth, dlat: np.ndarray, dlon: np.ndarray, k: slice,
               table: SegmentTable | None) -> None:
    """ECEF state, attitude, specific force and body rate on the grid points k of `out`."""
    t, lat, lon, v = out.t[k], out.lat[k], out.lon[k], out.v_ned[k]
    p = profiles(sc, t, table)
    _, dv = _ned_velocity(p)
    r = earth.geodetic_to_ecef(lat, lon, out.h[k])
    c_en = earth.ecef_to_ned_matrix(lat, lon)
    w_en = np.stack([dlon * np.cos(lat), -dlat, -dlon * np.sin(lat)], -1)
    w_ie = np.stack([earth.OMEGA_E * np.cos(lat), np.zeros_like(lat), -earth.OMEGA_E * np.sin(lat)], -1)
    v_e = np.einsum("nij,nj->ni", c_en, v)
    a_e = np.einsum("nij,nj->ni", c_en, dv + np.cross(w_en, v))
    # The body's attitude: the road's, plus the ride on the suspension (not the path's: v above).
    pitch, pitch_dot, roll, roll_dot = p.pitch, p.pitch_dot, p.roll, p.roll_dot
    if sc.ride.enabled:
        dp, dp_dot, dr, dr_dot = ride(sc.ride, t, p.speed, p.speed_dot)
        pitch, pitch_dot, roll, roll_dot = pitch + dp, pitch_dot + dp_dot, roll + dr, roll_dot + dr_dot
    c_nb = earth.euler_to_dcm(p.yaw, pitch, roll)
    c_eb = c_en @ c_nb
    f_e = a_e + 2.0 * np.cross(earth.OMEGA_VEC, v_e) - earth.gravity_ecef(r)
    # Euler-rate part of the body rate (z-y-x: roll rate about the body's x axis)
    sr, cr, sp, cp = np.sin(roll), np.cos(roll), np.sin(pitch), np.cos(pitch)
    w_nb = np.stack([roll_dot - p.yaw_dot * sp, pitch_dot * cr + p.yaw_dot * sr * cp,
                     -pitch_dot * sr + p.yaw_dot * cr * cp], -1)
    out.r_ecef[k], out.v_ecef[k], out.a_ecef[k], out.c_eb[k] = r, v_e, a_e, c_eb
    out.q_eb[k] = earth.dcm_to_quat(c_eb)
    out.ypr[k] = np.stack([p.yaw, pitch, roll], -1)
    out.f_body[k] = np.einsum("nji,nj->ni", c_eb, f_e)
    out.w_ib_body[k] = np.einsum("nji,nj->ni", c_nb, w_ie + w_en) + w_nb


def ideal_increments(tr: Truth) -> tuple[np.ndarray, np.ndarray]:
    """Exact (delta-theta, delta-v) for each IMU interval of the truth grid."""
    sub = tr.substeps
    ends = np.arange(0, len(tr.t), sub)
    c_ib_ends = earth.rot_z(earth.OMEGA_E * tr.t[ends]) @ tr.c_eb[ends]  # inertial frame = ECEF at t = 0
    c0, c1 = c_ib_ends[:-1], c_ib_ends[1:]
    dtheta = earth.dcm_to_rotvec(np.swapaxes(c0, -1, -2) @ c1)
    h = tr.t[1] - tr.t[0] if tr.step is None else tr.step
    w = np.ones(sub + 1)
    w[1:-1:2], w[2:-1:2] = 4.0, 2.0
    w = w * h / 3.0
    # Composite Simpson of the inertial specific force over each interval, a chunk of intervals at a time.
    integral = np.empty((len(ends) - 1, 3))
    per = max(1, CHUNK // sub)
    for a in range(0, len(ends) - 1, per):
        b = min(a + per, len(ends) - 1)
        g = slice(ends[a], ends[b] + 1)
        f_i = np.einsum("nij,nj->ni", earth.rot_z(earth.OMEGA_E * tr.t[g]) @ tr.c_eb[g], tr.f_body[g])
        idx = (ends[a:b] - ends[a])[:, None] + np.arange(sub + 1)
        integral[a:b] = np.einsum("k,nkj->nj", w, f_i[idx])
    dv = np.einsum("nji,nj->ni", c0, integral)
    return dtheta, dv
