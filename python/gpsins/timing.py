"""Time alignment: GPS time for every IMU sample from the logger's system-time stamps.

Stamps follow `stamp = system clock at the frame's first byte + a constant
latency per device + non-negative jitter`. The latencies cannot be seen in the
stamps, so they are configuration (for the GPS stream: the receiver's delay
from its measurement epoch to the first byte of ID 23, plus the logger's).

Two methods:

- ``report`` (seed 004, 4.3.2): IMU start = GPS time of the first GPS sample
  minus the difference of the two sensors' first system stamps; sample k at
  start + k / 64 s. Every dropped frame shifts all later samples by 1/64 s.
- ``robust`` (default): system time -> GPS time from every ID 23 (its time of
  week against its stamp), fitted along the lower envelope of the stamps
  (jitter only ever delays a stamp) per clock segment, so a realtime clock step
  splits the fit instead of bending it; then the IMU's own clock: the frame
  counter, unwrapped, gives each sample's index, and t = t0 + P n is fitted
  along the lower envelope of the mapped stamps. Dropped frames leave gaps;
  the IMU's clock drift is estimated as P against the GPS-disciplined time.

The lower envelope is the line under all points that minimises the summed
residual (a linear programme); its optimum is the edge of the points' lower
convex hull above their mean abscissa, found here with Qhull.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import ConvexHull, QhullError

METHODS = ("robust", "report")


class AlignmentError(ValueError):
    pass


def lower_envelope(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(a, b) of the line y = a + b x with y_i >= a + b x_i minimising sum(y_i - a - b x_i)."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if len(x) < 2 or np.ptp(x) == 0:
        raise AlignmentError("lower envelope needs at least two distinct abscissae")
    x0, y0 = x.mean(), y.min()
    xs, ys = (x - x0) / np.ptp(x), y - y0
    try:
        hull = ConvexHull(np.column_stack([xs, ys]))
        pts = np.unique(hull.vertices)
    except QhullError:  # all points on a line
        pts = np.array([np.argmin(xs), np.argmax(xs)])
    px, py = xs[pts], ys[pts]
    order = np.argsort(px)
    px, py = px[order], py[order]
    # Lower chain of the hull vertices (monotone chain over the few hull points).
    chain: list[int] = []
    for i in range(len(px)):
        while len(chain) >= 2:
            a, b = chain[-2], chain[-1]
            if (px[b] - px[a]) * (py[i] - py[a]) - (py[b] - py[a]) * (px[i] - px[a]) <= 0:
                chain.pop()
            else:
                break
        chain.append(i)
    k = int(np.clip(np.searchsorted(px[chain], 0.0) - 1, 0, len(chain) - 2))
    i, j = chain[k], chain[k + 1]
    slope = (py[j] - py[i]) / (px[j] - px[i])
    a_s = py[i] - slope * px[i]
    b = slope / np.ptp(x)
    return float(y0 + a_s - b * x0), float(b)


@dataclass
class ClockMap:
    """System time -> GPS time (s of the first week) per clock segment."""

    starts: np.ndarray  # first GPS record index of each segment (in stream order)
    offset: np.ndarray  # per segment: system stamp - latency at GPS time t_ref
    rate: np.ndarray  # per segment: d(system) / d(GPS)
    t_ref: float
    steps_s: list[float] = field(default_factory=list)
    residual_s: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def to_gps(self, stamps: np.ndarray, segment: np.ndarray) -> np.ndarray:
        return self.t_ref + (stamps - self.offset[segment]) / self.rate[segment]


def _steps(values: np.ndarray, threshold_s: float, window: int = 10) -> np.ndarray:
    """Indices i where the lower envelope of `values` (a clock offset plus non-negative
    delays) moves by more than the threshold: a jump whose window minimum after it
    differs from the one before. A frame delayed in a queue is a lone upward jump."""
    d = np.diff(values)
    cand = np.flatnonzero(np.abs(d - np.median(d)) > threshold_s) + 1
    out: list[int] = []
    for i in cand:
        if out and i - out[-1] < window:
            continue
        before = values[max(0, i - window):i].min()
        after = values[i:i + window].min()
        if abs(after - before) > threshold_s:
            out.append(int(i))
    return np.array(out, dtype=np.int64)


def fit_gps_clock(tow: np.ndarray, stamps: np.ndarray, latency_s: float, step_threshold_s: float = 0.02) -> ClockMap:
    """Map system time to GPS time from the measurement blocks' (time of week, stamp) pairs."""
    tow = np.asarray(tow, dtype=float)
    s = np.asarray(stamps, dtype=float) - latency_s
    if len(tow) < 3:
        raise AlignmentError(f"need at least 3 GPS measurement blocks to map the clock, got {len(tow)}")
    t_ref = float(tow[0])
    lag = s - (tow - t_ref)
    cuts = _steps(lag, step_threshold_s)
    starts = np.concatenate([[0], cuts])
    ends = np.concatenate([cuts, [len(tow)]])
    off, rate, resid = [], [], np.empty(len(tow))
    for a, b in zip(starts, ends):
        if b - a >= 2 and np.ptp(tow[a:b]) > 0:
            o, r = lower_envelope(tow[a:b] - t_ref, s[a:b])
        else:  # a lone block between two steps: the nominal rate
            o, r = float(np.min(lag[a:b])), 1.0
        off.append(o)
        rate.append(r)
        resid[a:b] = s[a:b] - (o + r * (tow[a:b] - t_ref))
    steps = [float(off[i] - off[i - 1]) for i in range(1, len(off))]
    return ClockMap(starts, np.array(off), np.array(rate), t_ref, steps, resid)


def unwrap_counter(counter: np.ndarray, stamps: np.ndarray, period_s: float) -> np.ndarray:
    """Sample index of each frame from its 8-bit counter; a gap longer than 256 frames is
    resolved with the stamps (the multiple of 256 nearest to what they say)."""
    c = np.asarray(counter, dtype=np.int64)
    step = np.diff(c) % 256
    step[step == 0] = 256  # a repeated counter value: 256 frames later
    by_stamp = np.diff(np.asarray(stamps, dtype=float)) / period_s
    extra = np.round((by_stamp - step) / 256.0)
    step = step + 256 * np.maximum(extra, 0).astype(np.int64)
    return np.concatenate([[0], np.cumsum(step)])


@dataclass
class Alignment:
    method: str
    imu_t: np.ndarray  # GPS time (s since the start of `week`) of each IMU record
    week: int
    imu_index: np.ndarray  # sample index from the counter (robust) or the record number (report)
    gaps: list[tuple[int, int]]  # (record index after the gap, frames missing)
    imu_period_s: float
    imu_clock_ppm: float
    gps_residual_s: np.ndarray  # lower-envelope residuals of the GPS stamps (jitter as seen)
    imu_residual_s: np.ndarray
    steps_s: list[float]

    def summary(self) -> dict:
        def pct(x):
            return {k: float(np.percentile(x, p)) for k, p in (("median", 50), ("p99", 99))} if len(x) else {}
        return {"method": self.method, "week": self.week, "imu_samples": int(len(self.imu_t)),
                "imu_frames_missing": int(sum(g[1] for g in self.gaps)), "gaps": len(self.gaps),
                "imu_period_s": self.imu_period_s, "imu_clock_ppm": self.imu_clock_ppm,
                "clock_steps_s": self.steps_s, "gps_stamp_residual_s": pct(self.gps_residual_s),
                "imu_stamp_residual_s": pct(self.imu_residual_s)}


def align(gps_tow: np.ndarray, gps_stamps: np.ndarray, week: int, imu_stamps: np.ndarray, imu_counter: np.ndarray,
          rate_hz: float, *, method: str = "robust", gps_latency_s: float = 0.0, imu_latency_s: float = 0.0,
          step_threshold_s: float = 0.02) -> Alignment:
    """GPS time of every IMU record (see the module doc for the methods)."""
    if method not in METHODS:
        raise AlignmentError(f"method must be one of {', '.join(METHODS)}, got '{method}'")
    gps_tow = np.asarray(gps_tow, dtype=float)
    imu_stamps = np.asarray(imu_stamps, dtype=float)
    if len(imu_stamps) < 2:
        raise AlignmentError(f"need at least 2 IMU records, got {len(imu_stamps)}")
    period = 1.0 / rate_hz
    if method == "report":
        start = gps_tow[0] - (gps_stamps[0] - imu_stamps[0])
        k = np.arange(len(imu_stamps))
        return Alignment("report", start + k * period, week, k, [], period, 0.0, np.zeros(0), np.zeros(0), [])

    clock = fit_gps_clock(gps_tow, gps_stamps, gps_latency_s, step_threshold_s)
    # Give each IMU stamp its clock segment: the IMU stream shows the same steps.
    imu_seg = np.zeros(len(imu_stamps), dtype=np.int64)
    n_seg = len(clock.starts)
    if n_seg > 1:
        n_guess = unwrap_counter(imu_counter, imu_stamps, period)
        cuts = _steps(imu_stamps - n_guess * period, step_threshold_s)
        if len(cuts) != n_seg - 1:
            raise AlignmentError(f"the GPS stamps show {n_seg - 1} clock step(s), the IMU stamps {len(cuts)}")
        for c in cuts:
            imu_seg[c:] += 1
    mapped = clock.to_gps(imu_stamps - imu_latency_s, imu_seg)
    # Unwrap against the mapped times (immune to the clock steps).
    n = unwrap_counter(imu_counter, mapped, period)
    t0, p = lower_envelope(n.astype(float), mapped)
    t = t0 + p * n
    jumps = np.flatnonzero(np.diff(n) > 1)
    gaps = [(int(j + 1), int(n[j + 1] - n[j] - 1)) for j in jumps]
    return Alignment("robust", t, week, n, gaps, float(p), float((period / p - 1.0) * 1e6), clock.residual_s,
                     mapped - t, clock.steps_s)
