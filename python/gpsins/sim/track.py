"""A ride along a fixed 3-D track: a closed curve through points with bank angles.

The track is a periodic cubic spline through its points (north, east, down in
metres from the start point, local level frame at the start), parametrised by
the chord length u, with the bank angle (roll about the track's tangent) and
the ride speed splined the same way. The body's forward axis is the tangent:
yaw and pitch follow from the spline's first derivative, their rates from its
second, so attitude, velocity and acceleration stay one consistent function of
u(t).

Motion: u obeys du/dt = s(t) v(u) / |p'(u)|, v the speed at u and s(t) a
quintic smoothstep that starts the ride from rest and later stops it again.
The ODE is solved to 1e-12 with dense output; rates and accelerations are
evaluated from the ODE's right-hand side at the interpolated u, not from the
interpolant's derivative, so they are exactly the derivatives of the speed
law along the solution.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import solve_ivp
from scipy.interpolate import CubicSpline

KMH = 1.0 / 3.6


@dataclass
class Cover:
    """A stretch of track under a roof or between steel (by point index, inclusive):
    satellites under below_elevation_deg in the azimuth sector are blocked there."""
    points: tuple[int, int]
    below_elevation_deg: float = 90.0
    azimuth_deg: tuple[float, float] = (0.0, 360.0)
    flicker: float = 0.0
    flicker_period_s: float = 1.0
    label: str = ""


@dataclass
class TrackSpec:
    points: list  # [north, east, down, bank_deg, speed_kmh] per point; the last joins the first
    laps: int = 1
    rest_before_s: float = 300.0
    rest_after_s: float = 30.0
    ramp_s: float = 4.0  # smoothstep from rest to the track's speed, and back
    cover: list = field(default_factory=list)


class Track:
    def __init__(self, spec: TrackSpec, where: str = "[track]"):
        pts = np.asarray(spec.points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 5 or len(pts) < 4:
            raise ValueError(f"{where}: points must be at least 4 rows of [north, east, down, bank_deg, speed_kmh]")
        if np.any(pts[:, 4] <= 0):
            raise ValueError(f"{where}: every point's speed_kmh must be > 0 (use rest_before_s to stand still)")
        if not (isinstance(spec.laps, int) and spec.laps >= 1):
            raise ValueError(f"{where}: laps must be an integer >= 1")
        if not spec.ramp_s > 0:
            raise ValueError(f"{where}: ramp_s must be > 0")
        self.spec = spec
        closed = np.vstack([pts, pts[:1]])
        chord = np.linalg.norm(np.diff(closed[:, :3], axis=0), axis=1)
        if np.any(chord <= 0):
            raise ValueError(f"{where}: two consecutive points coincide")
        self.knots = np.concatenate([[0.0], np.cumsum(chord)])
        self.period = float(self.knots[-1])
        self.p = CubicSpline(self.knots, closed[:, :3], bc_type="periodic")
        self.bank = CubicSpline(self.knots, np.radians(closed[:, 3]), bc_type="periodic")
        self.speed = CubicSpline(self.knots, closed[:, 4] * KMH, bc_type="periodic")
        self._solve()

    # --- the speed law -------------------------------------------------------------------------
    def _ramp(self, tau):
        """Speed scale and its time derivative: up over ramp_s from 0, down over ramp_s from brake_at."""
        r = self.spec.ramp_s

        def step(x):
            x = np.clip(x, 0.0, 1.0)
            return x ** 3 * (10 - 15 * x + 6 * x * x), 30 * x ** 2 * (1 - x) ** 2 / r

        up, dup = step(tau / r)
        down, ddown = step((tau - self.brake_at) / r) if np.isfinite(self.brake_at) else (0.0 * tau, 0.0 * tau)
        return up * (1 - down), dup * (1 - down) - up * ddown

    def _rate(self, u):
        """(du/dt at full speed, its derivative d/du) at u."""
        d1, d2 = self.p(u, 1), self.p(u, 2)
        n = np.linalg.norm(d1, axis=-1)
        v, dv = self.speed(u), self.speed(u, 1)
        g = v / n
        dg = dv / n - v * np.sum(d1 * d2, -1) / n ** 3
        return g, dg

    def _solve(self):
        end = self.spec.laps * self.period
        self.brake_at = np.inf
        free = solve_ivp(lambda t, y: self._ramp(np.array([t]))[0] * self._rate(y)[0], (0.0, 1e9), [0.0],
                         method="DOP853", rtol=1e-12, atol=1e-12, dense_output=True,
                         events=_crossing(end), max_step=1.0)
        # Brake so the ride stops near the start point: begin when the distance left is what the
        # ramp-down covers at the start point's speed (half of speed x ramp_s).
        brake_u = end - 0.5 * self.speed(0.0) * self.spec.ramp_s / np.linalg.norm(self.p(0.0, 1))
        ts = np.linspace(free.t[0], free.t[-1], 200001)
        k = int(np.searchsorted(free.sol(ts)[0], brake_u))
        lo, hi = ts[max(k - 1, 0)], ts[min(k, len(ts) - 1)]
        for _ in range(60):  # bisection on the dense solution
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if free.sol(mid)[0] < brake_u else (lo, mid)
        self.brake_at = 0.5 * (lo + hi)
        self._free = free.sol
        stop = solve_ivp(lambda t, y: self._ramp(np.array([t]))[0] * self._rate(y)[0],
                         (self.brake_at, self.brake_at + self.spec.ramp_s), free.sol(self.brake_at),
                         method="DOP853", rtol=1e-12, atol=1e-12, dense_output=True, max_step=0.05)
        self._stop = stop.sol
        self.ride_s = self.brake_at + self.spec.ramp_s
        self.u_end = float(stop.y[0, -1])
        # Lap boundaries: the times u passes whole periods (the last lap ends at the stop).
        marks = [0.0]
        for k in range(1, self.spec.laps):
            target = k * self.period
            lo, hi = 0.0, self.brake_at
            for _ in range(80):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if free.sol(mid)[0] < target else (lo, mid)
            marks.append(0.5 * (lo + hi))
        marks.append(self.ride_s)
        self.lap_times = np.array(marks)

    def u_of(self, tau: np.ndarray):
        """(u, du/dt, d2u/dt2) at ride times tau (0 = the ride starts; at rest before and after)."""
        tau = np.asarray(tau, dtype=np.float64)
        u = np.zeros_like(tau)
        a = (tau > 0) & (tau < self.brake_at)
        b = (tau >= self.brake_at) & (tau < self.ride_s)
        if a.any():
            u[a] = self._free(tau[a])[0]
        if b.any():
            u[b] = self._stop(tau[b])[0]
        u[tau >= self.ride_s] = self.u_end
        s, ds = self._ramp(tau)
        g, dg = self._rate(u)
        ud = s * g
        udd = ds * g + s * dg * ud
        moving = (tau > 0) & (tau < self.ride_s)
        return u, ud * moving, udd * moving

    # --- geometry --------------------------------------------------------------------------------
    def kinematics(self, tau: np.ndarray) -> dict:
        """Speed, yaw, pitch, roll and their rates along the track at ride times tau."""
        u, ud, udd = self.u_of(tau)
        d1, d2 = self.p(u, 1), self.p(u, 2)
        n1 = np.linalg.norm(d1, axis=-1)
        north, east, down = d1[:, 0], d1[:, 1], d1[:, 2]
        hz = np.hypot(north, east)
        hz_u = (north * d2[:, 0] + east * d2[:, 1]) / hz
        yaw_u = (north * d2[:, 1] - east * d2[:, 0]) / hz ** 2
        pitch_u = (hz * -d2[:, 2] - -down * hz_u) / (hz ** 2 + down ** 2)
        return dict(
            speed=n1 * ud, speed_dot=np.sum(d1 * d2, -1) / n1 * ud ** 2 + n1 * udd,
            yaw=np.arctan2(east, north), yaw_dot=yaw_u * ud,
            pitch=np.arctan2(-down, hz), pitch_dot=pitch_u * ud,
            roll=self.bank(u), roll_dot=self.bank(u, 1) * ud, u=u)

    def point_u(self, i: int) -> float:
        return float(self.knots[i % len(self.spec.points)])


def _crossing(end):
    def ev(t, y):
        return y[0] - end - 1.0  # run a little past the last lap's end; braking starts before it
    ev.terminal = True
    ev.direction = 1
    return ev
