"""The receiver's clock against system time: GPS time of week mapped to the logger's stamps (``ClockMap``,
``fit_gps_clock``, its steps), and an IMU frame counter unwrapped against its stamps.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from . import AlignmentError, DAMAGE_SHARE, GPS_WINDOW, MIN_SIDE, OUTLIER_TOL_S, STALL_MAX_S
from .envelope import damaged_low, median_slope, running_min, joint_lower_envelope


def _steps(values: np.ndarray, threshold_s: float, window: int = GPS_WINDOW) -> tuple[np.ndarray, float]:
    """Indices i where the floor of `values` (a clock offset plus non-negative delays, slope
    removed) moves by more than the threshold and stays: the minimum of the window from i
    on against the minimum of the window before it. An upward step is found at the start of
    the run where the difference is large, a downward one at its end. Also returns the
    threshold used (raised when the delays are large)."""
    left, right = running_min(values, window)
    # The minimum of m delays exceeds 7/m of their mean once in a thousand (exponential
    # delays; queueing behind other frames makes it more often): below 10/m, a step cannot
    # be told from a window that happened to be delayed throughout.
    floor = np.minimum(left, right)
    ok = np.isfinite(floor)
    mean_delay = float(np.median(values[ok] - floor[ok])) / np.log(2.0) if ok.any() else 0.0
    threshold_s = max(threshold_s, 10.0 * mean_delay / MIN_SIDE)
    d = right - left
    # Near the ends a window holds only a few values and their minimum still carries delays.
    i = np.arange(len(values))
    short = (i < MIN_SIDE) | (len(values) - i < MIN_SIDE)
    d[short | ~np.isfinite(d)] = 0.0
    out: list[int] = []
    for sign in (1.0, -1.0):
        big = np.concatenate([[False], sign * d > threshold_s, [False]])
        edges = np.flatnonzero(np.diff(big.astype(np.int8)))
        for a, b in zip(edges[::2], edges[1::2]):  # run [a, b)
            if sign > 0:
                out.append(int(a))
            else:  # the first value clearly on the lower floor
                low = left[a] + 0.5 * d[a:b].min()
                out.append(int(a + np.argmax(values[a:b] < low)) if np.any(values[a:b] < low) else int(b - 1))
    return np.array(sorted(c for c in out if 0 < c < len(values)), dtype=np.int64), threshold_s


@dataclass
class ClockMap:
    """System time -> GPS time (s of the first week) per clock segment."""

    starts: np.ndarray  # first GPS record index of each segment (in stream order)
    offset: np.ndarray  # per segment: system stamp - latency at GPS time t_ref
    rate: np.ndarray  # per segment: d(system) / d(GPS)
    t_ref: float
    steps_s: list[float] = field(default_factory=list)
    residual_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    step_after: np.ndarray = field(default_factory=lambda: np.zeros(0))  # GPS time of the last block before each step
    step_before: np.ndarray = field(default_factory=lambda: np.zeros(0))  # ... and of the first block after it
    damaged: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))  # blocks left out of the fit

    def to_gps(self, stamps: np.ndarray, segment: np.ndarray | int) -> np.ndarray:
        return self.t_ref + (stamps - self.offset[segment]) / self.rate[segment]


def _fit_segments(x: np.ndarray, s: np.ndarray, keep: np.ndarray, cuts: list, rate0: float
                  ) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """Offset of each segment between cuts and the system clock's rate (one for all: a clock
    step does not change it), along their joint lower envelope; and the steps, in system seconds."""
    starts = np.concatenate([[0], cuts]).astype(np.int64)
    seg = np.searchsorted(starts, keep, side="right") - 1
    if np.ptp(x[keep]) > 0 and any(np.ptp(x[keep][seg == g]) > 0 for g in np.unique(seg)):
        off, rate = joint_lower_envelope(x[keep], s[keep], seg)
    else:
        rate = rate0
        off = np.array([np.min(s[keep][seg == g] - rate * x[keep][seg == g]) for g in range(len(starts))])
    return off, np.full(len(off), rate), [float(d) for d in np.diff(off)]


def _spurious_steps(x: np.ndarray, s: np.ndarray, keep: np.ndarray, rate: float, cuts: list, steps: list[float],
                    threshold: float) -> set[int]:
    """Cuts that are not clock steps: one whose fitted size is below the threshold (the floor
    only looked different); an upward step undone by a downward one of the same size within
    STALL_MAX_S (a host stall longer than the window, not two clock steps); or a step back where the
    blocks' stamps never ran back although they come closer together than its size (the logger keeps
    a sensor's stamps increasing but where the clock was set back: the blocks before it were held,
    as when the GPS port is first read late, and no step up precedes it)."""
    small = [i for i, d in enumerate(steps) if abs(d) < threshold]
    if small:
        return {min(small, key=lambda i: abs(steps[i]))}
    for i in range(len(steps) - 1):
        up, down = steps[i], steps[i + 1]
        if up > 0 > down and abs(up + down) < max(threshold, 0.1 * up) and x[cuts[i + 1]] - x[cuts[i]] < STALL_MAX_S:
            return {i, i + 1}
    for i, d in enumerate(steps):
        c = int(np.searchsorted(keep, cuts[i]))
        near = keep[max(0, c - GPS_WINDOW):c + GPS_WINDOW]
        if len(near) > 1 and rate * np.max(np.diff(x[near])) < -d and not np.any(np.diff(s[near]) < 0):
            return {i}
    return set()


def fit_gps_clock(tow: np.ndarray, stamps: np.ndarray, latency_s: float, step_threshold_s: float = 0.01) -> ClockMap:
    """Map system time to GPS time from the measurement blocks' (time of week, stamp) pairs."""
    tow = np.asarray(tow, dtype=float)
    s = np.asarray(stamps, dtype=float) - latency_s
    good = np.isfinite(tow) & np.isfinite(s)
    if good.sum() < 3:
        raise AlignmentError(f"need at least 3 GPS measurement blocks (ID 23) with a stamp to map the clock, "
                             f"got {int(good.sum())}")
    t_ref = float(tow[good][0])
    x = tow - t_ref
    order = np.argsort(x[good], kind="stable")
    rate0 = median_slope(x[good][order], s[good][order], min(10.0, 0.25 * np.ptp(x[good])))
    if not np.isfinite(rate0) or rate0 <= 0:
        raise AlignmentError(f"the GPS stamps do not advance with GPS time (rate {rate0:.3g}): the ID 23 stamps "
                             f"or times of week are unusable")
    lag = s - rate0 * x
    damaged = ~good
    # The tolerance is what a damaged stamp left in may cost in GPS time: served S times faster,
    # a system second is S GPS seconds.
    damaged[good] = damaged_low(lag[good], GPS_WINDOW, OUTLIER_TOL_S * rate0, 1 + GPS_WINDOW // DAMAGE_SHARE)
    keep = np.flatnonzero(~damaged)
    if len(keep) < 3:
        raise AlignmentError(f"only {len(keep)} GPS measurement blocks have a usable stamp")
    found, threshold = _steps(lag[keep], step_threshold_s)
    cuts = list(keep[found])
    while True:
        off_a, rate_a, steps = _fit_segments(x, s, keep, cuts, rate0)
        drop = _spurious_steps(x, s, keep, rate0, cuts, steps, threshold)
        if not drop:
            break
        cuts = [c for i, c in enumerate(cuts) if i not in drop]
    cuts = np.array(cuts, dtype=np.int64)
    starts = np.concatenate([[0], cuts]).astype(np.int64)
    seg = np.searchsorted(starts, np.arange(len(tow)), side="right") - 1
    resid = s - (off_a[seg] + rate_a[seg] * x)
    after = np.array([x[keep[keep < c][-1]] for c in cuts]) + t_ref
    before = np.array([x[keep[keep >= c][0]] for c in cuts]) + t_ref
    return ClockMap(starts, off_a, rate_a, t_ref, steps, resid, after, before, damaged)


def unwrap_counter(counter: np.ndarray, times: np.ndarray, period_s: float, usable: np.ndarray | None = None,
                   window: int = 640) -> np.ndarray:
    """Sample index of each frame from its 8-bit counter; a gap of 256 frames or more is
    resolved with the times (GPS times, or stamps without clock steps): the multiple of 256
    nearest to what the frames on each side of it say. Each side's time is the minimum over
    up to `window` usable frames, referred to the gap's edge by the counter: delays only ever
    add, and a host stall delays a run of frames, so the window must outlast the stalls."""
    c = np.asarray(counter, dtype=np.int64)
    t = np.asarray(times, dtype=float)
    ok = np.ones(len(c), dtype=bool) if usable is None else np.asarray(usable, dtype=bool)
    n = counter_steps(c)
    e = t - period_s * n  # flat except at gaps of whole counter periods (and delays)
    e_ok = np.where(ok, e, np.inf)
    cand = np.flatnonzero((np.diff(e) / period_s) > 128) + 1
    extra = np.zeros(len(c), dtype=np.int64)
    added = 0  # periods found before the current candidate
    for i in cand:
        lo = max(0, i - window)
        # Frames before i with the periods found up to each of them taken off.
        found = added - np.cumsum(extra[lo:i][::-1])[::-1] + extra[lo:i]
        before = np.min(e_ok[lo:i] - 256 * period_s * found) if i > lo else np.inf
        after = e_ok[i:i + window].min() - 256 * period_s * added
        if np.isfinite(before) and np.isfinite(after):
            extra[i] = max(0, int(np.round((after - before) / period_s / 256.0)))
            added += extra[i]
    return n + 256 * np.cumsum(extra)


def counter_steps(counter: np.ndarray) -> np.ndarray:
    step = np.diff(np.asarray(counter, dtype=np.int64)) % 256
    step[step == 0] = 256
    return np.concatenate([[0], np.cumsum(step)])
