"""The data-set doctor: checks a data set's data against what its TOML declares, before a replay.

Each check measures something the declaration predicts and says what it measured:

- accelerometer norm at rest against local (normal) gravity: a unit of g against m/s^2;
- gyro at rest against the Earth's rate plus a plausible MEMS bias: deg/s data declared rad/s;
- the IMU's heading rate (about the measured vertical) against the GNSS course rate, through the
  turns: its slope catches rad/s data declared deg/s, its lag (cross-correlation) a time-scale or
  leap-second mistake and any IMU-GNSS offset over 50 ms;
- gravity in body axes at rest against the declared mounting (FRD: z down);
- the filter mode against the content (tight without pseudoranges, loose without any GNSS);
- the IMU and GNSS spans overlapping, and the outages and the reference inside them.

"Rest" is where the fixes' speed is under REST_SPEED_MPS (or, without velocities, the IMU's specific
force is steady). An error stops a replay unless it is forced; a warning goes into run.json.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .. import _core, evaluate
from . import fixes as dataset_fixes
from ..formats import gpstime

REST_SPEED_MPS = 0.2
MOVING_SPEED_MPS = 1.0  # course defined well enough from the fixes' positions
BIN_S = 1.0  # IMU averages for the rest and vertical estimates
GRID_S = 0.02  # resolution of the lag search
MAX_LAG_S = 30.0  # covers a leap-second count (18 s) and a UTC/GPS mix-up
OFFSET_WARN_S = 0.05
OFFSET_ERROR_S = 1.0
MIN_CORRELATION = 0.5  # below this the lag says nothing
MIN_TURNING_DEG = 90.0  # total course change needed before the gyro scale is judged
GYRO_REST_MAX_RAD_S = math.radians(3.0)  # Earth rate plus a consumer MEMS bias (0.5 deg/s) several times
G_TOLERANCE = 0.05  # relative: a scale error a real accelerometer does not have
TILT_WARN_DEG, TILT_ERROR_DEG = 30.0, 60.0
G_NOMINAL = 9.80665
DEG_PER_RAD = math.degrees(1.0)
ORDER = ("mode", "spans", "outages", "reference", "accelerometer", "gyro", "mounting", "heading", "time offset",
         "motion")


@dataclass
class Finding:
    check: str
    level: str  # "ok", "warning", "error", "skipped"
    text: str

    def line(self) -> str:
        return f"{self.level}: {self.check}: {self.text}"


@dataclass
class Diagnosis:
    findings: list[Finding] = field(default_factory=list)

    def add(self, check: str, level: str, text: str) -> None:
        self.findings.append(Finding(check, level, text))

    def errors(self) -> list[Finding]:
        return [f for f in self.findings if f.level == "error"]

    def warnings(self) -> list[Finding]:
        return [f for f in self.findings if f.level == "warning"]

    def as_dict(self) -> list[dict]:
        return [vars(f) for f in self.findings]


def _bins(t: np.ndarray, x: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
    """Means of x over consecutive windows of `width` seconds (empty ones dropped): times, values."""
    k = np.floor((t - t[0]) / width).astype(np.int64)
    n = np.bincount(k)
    ok = n > 0
    mean = np.column_stack([np.bincount(k, weights=x[:, j])[ok] / n[ok] for j in range(x.shape[1])])
    return t[0] + (np.flatnonzero(ok) + 0.5) * width, mean


def _local_ned(fixes) -> tuple[np.ndarray, float, float]:
    """The fixes' positions in a local NED frame at the first one (metres), and its latitude and height."""
    llh = fixes.llh()
    c = evaluate.c_en(llh[:1, 0], llh[:1, 1])[0]  # NED -> ECEF
    return (fixes.r_ecef - fixes.r_ecef[0]) @ c, float(llh[0, 0]), float(llh[0, 2])


def diagnose(ds, modes=("loose",)) -> Diagnosis:
    """Every check on a loaded data set (``dataset.load.load``) for the filter modes to be run."""
    d = Diagnosis()
    _check_content(ds, modes, d)
    t, f, w = _imu_rates(ds)
    _check_spans(ds, t, d)
    fixes = ds.fixes if ds.fixes is not None and len(ds.fixes) >= 3 else None
    if fixes is None or not len(t):
        d.add("motion", "skipped", "no receiver fixes: the IMU is not compared with GNSS motion")
        return d
    ned, lat, height = _local_ned(fixes)
    tb, fb = _bins(t, f, BIN_S)
    del f  # the rest needs only its bins (an hour at 200 Hz: 18 MB)
    _, wb = _bins(t, w, BIN_S)
    lag = _check_heading(ds, t, w, tb, fb, fixes, ned, d)
    # A time-scale mistake would put the rest where the vehicle moves: rest on the time base found.
    shift = lag if lag is not None and abs(lag) >= OFFSET_ERROR_S else 0.0
    rest = _speed_at(fixes.t_abs, ned, tb - shift) < REST_SPEED_MPS
    _check_rest(fb, wb, rest, float(_core.normal_gravity(lat, height)), d)
    d.findings.sort(key=lambda f: ORDER.index(f.check))
    return d


def _imu_rates(ds) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.asarray(ds.imu.t_abs, float)
    if len(t) < 3:
        return np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3))
    dt = np.diff(t)
    ok = dt > 0
    ok = slice(None) if ok.all() else ok  # a mask only where a step is dropped: it copies (35 MB for an hour)
    return t[1:][ok], ds.imu.dv_mps[1:][ok] / dt[ok, None], ds.imu.dtheta_rad[1:][ok] / dt[ok, None]


def _check_content(ds, modes, d: Diagnosis) -> None:
    has_fixes = ds.fixes is not None and len(ds.fixes) > 0
    has_pr = ds.pseudoranges is not None and len(ds.pseudoranges) > 0
    what = f"[gnss] format {ds.gnss_format!r} gives " + (
        "fixes and pseudoranges" if has_fixes and has_pr else "fixes only" if has_fixes else
        "pseudoranges only" if has_pr else "nothing")
    if "tight" in modes and not has_pr:
        d.add("mode", "error", f"--mode tight needs pseudoranges; {what}")
    elif "tight" in modes and not (ds.navigation is not None and ds.navigation.ephemerides):
        d.add("mode", "error", f"--mode tight needs ephemerides (a navigation file); {what}, none")
    elif not has_fixes and not has_pr:
        d.add("mode", "error", f"{what}: no GNSS to aid the IMU")
    else:
        d.add("mode", "ok", f"{'/'.join(modes)}: {what}")


def _week_tow(t: float) -> str:
    w = int(t // gpstime.SECONDS_PER_WEEK)
    return f"week {w} {t - w * gpstime.SECONDS_PER_WEEK:.1f} s"


def _check_spans(ds, t_imu: np.ndarray, d: Diagnosis) -> None:
    try:
        g0, g1 = ds.gnss_span()
    except ValueError:
        return
    if not len(t_imu):
        d.add("spans", "error", "fewer than 3 IMU samples")
        return
    i0, i1 = float(t_imu[0]), float(t_imu[-1])
    overlap = min(i1, g1) - max(i0, g0)
    spans = f"IMU {_week_tow(i0)} to {_week_tow(i1)}, GNSS {_week_tow(g0)} to {_week_tow(g1)}"
    if overlap <= 0:
        d.add("spans", "error", f"{spans}: they do not overlap (a file from another day or week, or another "
                                f"time scale?)")
        return
    share = overlap / max(i1 - i0, 1e-9)
    d.add("spans", "ok" if share > 0.5 else "warning", f"{spans}: {100 * share:.0f} % of the IMU's span has GNSS")
    if ds.outages is not None:
        sched = ds.outage_schedule()
        d.add("outages", "ok" if len(sched) else "error",
              f"[scoring] outages {ds.outages.text()}: {len(sched)} outage(s) inside the GNSS span")
    if ds.reference is not None:
        inside = int(np.sum((ds.reference.t_abs >= max(i0, g0)) & (ds.reference.t_abs <= min(i1, g1))))
        d.add("reference", "ok" if inside else "error",
              f"{inside} of {len(ds.reference)} reference epochs inside the IMU and GNSS spans")


def _speed_at(t_fix: np.ndarray, ned: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Horizontal speed from the fixes' positions (central differences), at times t."""
    v = np.gradient(ned[:, :2], t_fix, axis=0)
    s = np.hypot(v[:, 0], v[:, 1])
    out = np.interp(t, t_fix, s, left=np.nan, right=np.nan)
    return np.where(np.isnan(out), np.inf, out)


def _check_rest(fb: np.ndarray, wb: np.ndarray, rest: np.ndarray, g: float, d: Diagnosis) -> None:
    if rest.sum() < 2:
        # No standstill: the median over the whole record (a vehicle's mean acceleration is small).
        norm = float(np.median(np.linalg.norm(fb, axis=1)))
        where, tol = "over the whole record (no standstill)", 3 * G_TOLERANCE
    else:
        norm = float(np.median(np.linalg.norm(fb[rest], axis=1)))
        where, tol = f"at rest ({int(rest.sum())} s)", G_TOLERANCE
    ratio = norm / g
    text = f"specific force {where} {norm:.3f} m/s^2 against local gravity {g:.3f}"
    if abs(ratio * G_NOMINAL - 1.0) < 0.2:
        d.add("accelerometer", "error", f"{text}: the data look like g declared as m/s^2 (accel_unit)")
    elif abs(ratio / G_NOMINAL - 1.0) < 0.2:
        d.add("accelerometer", "error", f"{text}: the data look like m/s^2 declared as g (accel_unit)")
    elif abs(ratio - 1.0) > tol:
        d.add("accelerometer", "error", f"{text} ({ratio:.2f}x): check accel_unit and the columns")
    else:
        d.add("accelerometer", "ok", text)
    if rest.sum() < 2:
        d.add("gyro", "skipped", "no standstill to read the gyro's rest rate")
        d.add("mounting", "skipped", "no standstill to read gravity in body axes")
        return
    rate = float(np.median(np.linalg.norm(wb[rest], axis=1)))
    text = f"rate at rest {math.degrees(rate):.3f} deg/s (the Earth's 0.004 plus the unit's bias; 3 or more is no bias)"
    if rate > GYRO_REST_MAX_RAD_S:
        hint = ": the data look like deg/s declared as rad/s (gyro_unit)" if rate / DEG_PER_RAD < 0.05 else ""
        d.add("gyro", "error", text + hint)
    else:
        d.add("gyro", "ok", text)
    f = np.median(fb[rest], axis=0)
    tilt = math.degrees(math.acos(np.clip(-f[2] / np.linalg.norm(f), -1.0, 1.0)))
    text = (f"gravity at rest in body axes (FRD) {np.round(-f / np.linalg.norm(f), 2).tolist()}, "
            f"{tilt:.0f} deg from body down")
    level = "error" if tilt > TILT_ERROR_DEG else "warning" if tilt > TILT_WARN_DEG else "ok"
    d.add("mounting", level, text + (": check imu_to_body (body z is down)" if level != "ok" else ""))


def _horizontal_velocity(ds, fixes, ned: np.ndarray) -> tuple[np.ndarray, str]:
    """The fixes' horizontal velocity (north, east) at their epochs: the receiver's own, moved back
    by its lag (``[gnss] velocity_lag_s``, or measured), where it gives one; else central differences
    of the positions (centred on the epoch: no lag)."""
    v = fixes.v_ned_mps
    if v is not None and np.isfinite(v[:, :2]).all(axis=1).mean() > 0.8:
        lag = ds.velocity_lag_s
        if lag == "measured":
            found = dataset_fixes.velocity_lag(fixes)
            lag = max(0.0, found["lag_s"]) if found else 0.0
        good = np.isfinite(v[:, :2]).all(axis=1)
        vh = np.column_stack([np.interp(fixes.t_abs, fixes.t_abs[good] - lag, v[good, j]) for j in range(2)])
        return vh, f"the receiver's velocities (lag {lag:.3f} s taken out)"
    return np.gradient(ned[:, :2], fixes.t_abs, axis=0), "the fixes' positions"


def _smooth(x: np.ndarray, width_s: float) -> np.ndarray:
    n = max(1, int(round(width_s / GRID_S)))
    return np.convolve(x, np.ones(n) / n, mode="same")


def _check_heading(ds, t, w, tb, fb, fixes, ned, d: Diagnosis) -> float | None:
    """IMU heading rate about the measured vertical against the course rate of the fixes; the lag
    found (None: not measured)."""
    down = -fb / np.linalg.norm(fb, axis=1, keepdims=True)
    yaw_rate = np.empty(len(t))  # FRD: a turn to the right is positive, as heading
    for a in range(0, len(t), 1 << 16):  # by blocks: no whole-rate copy of the bins' verticals
        k = np.clip(np.searchsorted(tb, t[a:a + (1 << 16)]), 0, len(tb) - 1)
        yaw_rate[a:a + len(k)] = np.einsum("ij,ij->i", w[a:a + len(k)], down[k])
    t_fix = fixes.t_abs
    v, source = _horizontal_velocity(ds, fixes, ned)
    speed = np.hypot(v[:, 0], v[:, 1])
    moving = speed > MOVING_SPEED_MPS
    # The antenna's course leads the IMU's by its lever forward over the speed (a point ahead on a
    # turning body moves sideways with the turn): taken out with the IMU's own rate.
    ahead = float(ds.antenna_m[0])
    rate_at_fix = np.interp(t_fix, t, yaw_rate)
    lead = np.where(moving, rate_at_fix * ahead / np.maximum(speed, 1e-9), 0.0)
    course = np.unwrap(np.arctan2(v[:, 1], v[:, 0])) - lead
    course_rate = np.where(moving, np.gradient(course, t_fix), 0.0)
    turning = math.degrees(float(np.sum(np.abs(np.diff(course))[moving[1:] & moving[:-1]])))
    if turning < MIN_TURNING_DEG:
        d.add("heading", "skipped", f"{turning:.0f} deg of course change while moving: too little to compare "
                                    f"the gyro with")
        return None
    grid = np.arange(max(t[0], t_fix[0]), min(t[-1], t_fix[-1]), GRID_S)
    if len(grid) < int(2 * MAX_LAG_S / GRID_S):
        d.add("heading", "skipped", "the IMU and the fixes share too short a span")
        return None
    # Both on one grid and smoothed over one epoch of the fixes (the course rate's own noise): the
    # IMU's rate as the heading's change over each step, the course rate interpolated.
    epoch = float(np.median(np.diff(t_fix)))
    cum = np.concatenate([[0.0], np.cumsum(yaw_rate[1:] * np.diff(t))])
    m = np.interp(grid, t_fix, moving.astype(float)) > 0.5
    imu = _smooth(np.gradient(np.interp(grid, t, cum), GRID_S), epoch) * m
    gnss = _smooth(np.interp(grid, t_fix, course_rate), epoch) * m
    lag, rho = _lag(imu, gnss)
    # The slope through the origin, with the IMU moved by the lag found.
    shifted = np.interp(grid + lag, grid, imu) * m
    scale = float(np.sum(shifted * gnss) / max(np.sum(shifted ** 2), 1e-30))
    text = f"course rate (from {source}) / IMU heading rate {scale:.3f} over {turning:.0f} deg of turns"
    if rho < MIN_CORRELATION:
        d.add("heading", "warning", f"{text}, but they hardly correlate ({rho:.2f}): axes or mounting?")
        return None
    if abs(scale / DEG_PER_RAD - 1.0) < 0.2:
        d.add("heading", "error", f"{text}: the data look like rad/s declared as deg/s (gyro_unit)")
    elif abs(scale * DEG_PER_RAD - 1.0) < 0.2:
        d.add("heading", "error", f"{text}: the data look like deg/s declared as rad/s (gyro_unit)")
    elif abs(scale - 1.0) > 0.2:
        d.add("heading", "warning", f"{text}: a gyro scale error, or the wrong axis as vertical")
    else:
        d.add("heading", "ok", text)
    text = (f"IMU heading rate matches the course rate {abs(lag):.3f} s {'later' if lag > 0 else 'earlier'} "
            f"(correlation {rho:.2f}): [imu] time_offset_s about {ds.imu_time_offset_s - lag:+.3f}")
    # A hand-carried device's heading is not its course (gait, the hand): there only a time-scale mistake shows.
    car = ds.vehicle_kind == "car"
    warn = OFFSET_WARN_S if car else OFFSET_ERROR_S
    if not car:
        text += f" (not a car: its heading is not its course, only {OFFSET_ERROR_S:g} s or more counts)"
    level = "error" if abs(lag) >= OFFSET_ERROR_S else "warning" if abs(lag) > warn else "ok"
    hint = " (18 s: UTC against GPS time?)" if abs(abs(lag) - 18.0) < 1.0 else ""
    d.add("time offset", level, text + hint)
    return lag


def _lag(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """The shift s (seconds, within MAX_LAG_S) with a(t + s) most like b(t), to a fraction of a grid
    step (parabola through the peak), and the correlation coefficient there."""
    n = len(a)
    a, b = a - a.mean(), b - b.mean()
    size = 1 << int(np.ceil(np.log2(2 * n)))
    c = np.fft.irfft(np.fft.rfft(a, size) * np.conj(np.fft.rfft(b, size)), size)
    m = int(MAX_LAG_S / GRID_S)
    lags = np.concatenate([np.arange(0, m + 1), np.arange(-m, 0)])
    vals = np.concatenate([c[:m + 1], c[-m:]])
    i = int(np.argmax(vals))
    frac = 0.0
    if 0 < i < len(vals) - 1 and i not in (m, m + 1):  # neighbours on the same side of the lags
        y0, y1, y2 = vals[i - 1], vals[i], vals[i + 1]
        den = y0 - 2 * y1 + y2
        frac = 0.5 * (y0 - y2) / den if den < 0 else 0.0
    rho = float(vals[i] / max(math.sqrt(np.sum(a * a) * np.sum(b * b)), 1e-30))
    return float((lags[i] + frac) * GRID_S), rho
