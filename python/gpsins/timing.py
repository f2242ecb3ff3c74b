"""Time alignment: GPS time for every IMU sample from the logger's system-time stamps.

Stamps follow `stamp = system clock at the frame's first byte + a constant
latency per device + a non-negative delay`. The delay is usually a fraction of
a millisecond, but a loaded host holds frames for hundreds of milliseconds and
then stamps them all at once. The latencies cannot be seen in the stamps, so
they are configuration (for the GPS stream: the receiver's delay from its
measurement epoch to the first byte of ID 23, plus the logger's).

Two methods:

- ``report`` (the FOI report, 4.3.2): IMU start = GPS time of the first GPS sample
  minus the difference of the two sensors' first system stamps; sample k at
  start + k / 64 s. Every dropped frame shifts all later samples by 1/64 s.
- ``robust`` (default), in four stages:

  1. GPS clock: system time against every ID 23's time of week. The system
     clock's rate against GPS time is estimated first (a median of slopes, so a
     recording served faster than real time or a drifting clock is no special
     case) and removed; what is left is a clock offset that is constant between
     realtime clock steps, plus delays that are never negative. A stamp far
     below the floors of the stamps on both sides cannot be a delay: it is a
     damaged stamp and is left out (a few in a row or close together too: each
     floor is a low order statistic, not the minimum). "Far" is GPS time, what
     a damaged stamp left in would cost: served S times faster, S times fewer
     system seconds. A step is a change of the running minimum that lasts (the
     minimum over a window is blind to delays shorter than the window; the
     threshold grows with the delays). A step up undone by one down of the same
     size within 10 s is a host stall longer than the window, not two steps.
     The segments between steps share the rate and are fitted along their
     joint lower envelope, each with its own offset.
  2. Which IMU frames precede each step: the frames are in arrival order, so
     each step is one cut in the IMU stream. A coarse cut from the GPS time at
     which the GPS stream brackets the step (and, for a step over a second, the
     jump or drop it makes on the old map); then, over every frame that could
     lie on either side, the cut that makes the IMU clock's floor tightest
     (the lower envelope's objective with the cut as a free variable). Stamps
     alone cannot do it: a step of a whole number of counter periods, 4 s at
     64 Hz, looks exactly like a gap.
  3. The IMU's sample index from its 8-bit frame counter; across a gap of 256
     frames or more, the number of whole counter periods comes from the mapped
     times: the floors over 10 s on each side (a host stall outlasts a 400 Hz
     counter's 0.64 s period). The frame period is the configured rate's unless
     the stamps disagree by more than 1 %.
  4. The IMU's own clock: t = t0 + P n along the lower envelope of the mapped
     times, per stretch between gaps longer than ``PIECE_GAP_S`` (an unplugged
     or restarted IMU may resume with another phase); stretches too short to
     give a rate use the others' P. Dropped frames leave gaps; the IMU's clock
     drift is P against the GPS-disciplined time.

The lower envelope is the line under all points that minimises the summed
residual (a linear programme). With one slope and an offset per group, each
offset is the group's minimum of y - b x for a given slope b, so the objective
is convex and piecewise linear in b and its optimum lies at the slope of an
edge of a group's lower convex hull (Qhull).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

METHODS = ("robust", "report")
GPS_WINDOW = 30  # ID 23 blocks (3 s at 10 Hz) for running minima: longer than a host stall
IMU_WINDOW_S = 3.0
MIN_SIDE = 15  # blocks on each side before a step can be told from delays
OUTLIER_TOL_S = 0.0005  # GPS seconds: a stamp this far below the floors on both sides is damaged
DAMAGE_SHARE = 64  # a floor is the (1 + w // 64)-th smallest of w stamps: one damaged in 64 does not lower it
UNWRAP_WINDOW_S = 10.0  # longer than host stalls: the floor on each side of a gap
MEDIAN_FRAMES = 5  # frames whose median stands for one frame's time in the coarse cut
PIECE_GAP_S = 1.0  # an IMU gap this long may restart its clock: fit each side on its own
MARGIN_S = 2.0  # delays and stalls allowed for around a step's GPS bracket
RATE_MISMATCH = 0.01  # configured IMU rate this far from what the stamps show: use the stamps
LATE_S = 60.0  # a stamp this late is damaged, not delayed
STALL_MAX_S = 10.0  # an apparent step up and back down within this is a host stall
MIN_RATE_SPAN_S = 20.0  # an IMU stretch shorter than this takes the IMU period from the others
OVERLAP_SLACK_S = 600.0  # IMU stamps this far outside the GPS stamps cannot share their clock map


HULL_BLOCK = 1 << 16  # points per block of a long series' lower hull


class AlignmentError(ValueError):
    pass


def _lower_chain(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Indices of the vertices of the points' lower convex hull, by increasing x (x not all equal).

    A vertex of the whole hull is a vertex of the hull of any subset holding it: on a long
    series (a day of IMU samples) the hulls of blocks leave the only candidates, so that
    memory holds a block at a time. The coordinates are normalised the same way in both."""
    x0, y0, scale = x.mean(), y.min(), np.ptp(x)
    if len(x) <= HULL_BLOCK:
        return _chain((x - x0) / scale, y - y0)
    cand = np.concatenate([a + _chain((x[a:a + HULL_BLOCK] - x0) / scale, y[a:a + HULL_BLOCK] - y0)
                           for a in range(0, len(x), HULL_BLOCK)])
    return cand[_chain((x[cand] - x0) / scale, y[cand] - y0)]


def _chain(xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """``_lower_chain`` on normalised coordinates.

    A point above the chord of two others is no vertex: whole passes drop every point above the
    chord of its current neighbours at once (NumPy), which leaves few points on stamps, and a
    monotone chain finishes on those."""
    order = np.lexsort((ys, xs))
    sx = xs[order]
    first = np.ones(len(order), bool)
    first[1:] = sx[1:] != sx[:-1]  # the lowest point of each abscissa
    del sx
    pts = order[first]
    del order, first
    for _ in range(64):
        if len(pts) < 3:
            break
        px, py = xs[pts], ys[pts]
        cross = (px[1:-1] - px[:-2]) * (py[2:] - py[:-2]) - (py[1:-1] - py[:-2]) * (px[2:] - px[:-2])
        above = np.concatenate([[False], cross <= 0, [False]])
        if not above.any():
            break
        pts = pts[~above]
    px, py = xs[pts], ys[pts]
    chain: list[int] = []
    for i in range(len(px)):  # monotone chain over what is left
        while len(chain) >= 2:
            a, b = chain[-2], chain[-1]
            if (px[b] - px[a]) * (py[i] - py[a]) - (py[b] - py[a]) * (px[i] - px[a]) <= 0:
                chain.pop()
            else:
                break
        chain.append(i)
    return pts[chain]


def lower_envelope(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(a, b) of the line y = a + b x with y_i >= a + b x_i minimising sum(y_i - a - b x_i)."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if len(x) < 2 or np.ptp(x) == 0:
        raise AlignmentError("lower envelope needs at least two distinct abscissae")
    a, b = joint_lower_envelope(x, y, None)
    return float(a[0]), b


def counter_times(counter_s: np.ndarray, arrival_t_abs: np.ndarray) -> tuple[np.ndarray, dict]:
    """GPS times of samples from the sensor's own counter (seconds) and the logger's arrival times (NaN where
    none): the lower envelope of arrival against counter, so latency never makes a sample earlier than it
    arrived, and the counter's rate against the host's clock comes with it."""
    x = counter_s - counter_s[0]
    ok = np.isfinite(arrival_t_abs)
    a, b = lower_envelope(x[ok], arrival_t_abs[ok])
    t = a + b * x
    late_ms = (arrival_t_abs[ok] - t[ok]) * 1e3
    return t, {"counter_rate_ppm": (b - 1.0) * 1e6, "arrival_above_envelope_ms": {
        "median": float(np.median(late_ms)), "p95": float(np.percentile(late_ms, 95)), "max": float(late_ms.max())},
        "samples_with_arrival": int(ok.sum())}


def joint_lower_envelope(x: np.ndarray, y: np.ndarray, group: np.ndarray | None) -> tuple[np.ndarray, float]:
    """One slope b and an intercept a_g per group (``group`` None: one group): y_i >= a_g + b x_i minimising
    the summed residual. For a given b each a_g is the minimum of y - b x over its group, so the objective
    is convex and piecewise linear in b, with its optimum at the slope of an edge of some
    group's lower hull: those slopes are the only candidates."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    x0, y0 = x.mean(), y.min()
    xs, ys = x - x0, y - y0
    groups = np.unique(group) if group is not None else [None]
    hulls, sums, slopes = [], [], []
    for g in groups:
        if g is None:
            gx, gy = xs, ys  # one group: no copies (a day of IMU samples is 5.5 million)
        else:
            m = group == g
            gx, gy = xs[m], ys[m]
        h = _lower_chain(gx, gy) if len(gx) >= 2 and np.ptp(gx) > 0 else np.array([np.argmin(gy)])
        hulls.append((gx[h], gy[h]))
        sums.append((len(gx), gy.sum(), gx.sum()))
        slopes.extend(np.diff(gy[h]) / np.diff(gx[h]))
    if not slopes:
        raise AlignmentError("lower envelope needs at least two distinct abscissae in one group")
    cand = np.unique(slopes)

    def cost(b: float) -> float:
        return sum(sy - b * sx - n * np.min(hy - b * hx) for (n, sy, sx), (hx, hy) in zip(sums, hulls))

    b = float(cand[int(np.argmin([cost(c) for c in cand]))])
    a = np.array([np.min(hy - b * hx) for hx, hy in hulls])
    return y0 + a - b * x0, b


def _window_min(x: np.ndarray, w: int) -> np.ndarray:
    """min(x[i:i + w]) for every i with a full window (van Herk / Gil-Werman: block prefix and
    suffix minima, so the cost does not grow with w)."""
    n = len(x)
    blocks = -(-n // w)
    padded = np.full(blocks * w, np.inf)
    padded[:n] = x
    b = padded.reshape(blocks, w)
    prefix = np.minimum.accumulate(b, axis=1).ravel()
    suffix = np.minimum.accumulate(b[:, ::-1], axis=1)
    del b, padded
    suffix = suffix[:, ::-1].ravel()
    return np.minimum(suffix[:n - w + 1], prefix[w - 1:n])  # slices, not index arrays: no n-long temporaries


def _running_min(y: np.ndarray, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Minimum of the w values before i (i excluded) and of the w values from i on; inf where empty."""
    n = len(y)
    w = max(1, min(int(w), n))
    pad = np.full(w, np.inf)
    m = _window_min(np.concatenate([pad, y, pad]), w)  # m[j] = min over padded[j : j + w]
    return m[:n], m[w:w + n]


DAMAGE_BLOCK = 1 << 18  # values per block of _damaged_low
DAMAGE_SWEEPS = 8  # repeats of the damaged-stamp test with the damage found left out
DAMAGE_SUBBLOCKS = 4  # sub-blocks per neighbourhood of the damaged-stamp test


def _poisson_quantile(k: int, p: float = 1e-3) -> float:
    """The c with P(Poisson(c) < k) = p: the k-th smallest of w exponential delays of mean mu
    exceeds c mu / w with probability p (c = 6.9 for the minimum)."""
    lo, hi = 0.0, 100.0
    for _ in range(60):
        c = 0.5 * (lo + hi)
        tail = sum(math.exp(-c) * c ** j / math.factorial(j) for j in range(k))
        lo, hi = (c, hi) if tail > p else (lo, c)
    return hi


def _damaged_low(y: np.ndarray, w: int, tol: float, order: int = 1) -> np.ndarray:
    """Values below the floors of the w values before and after them by more than tol, each floor
    the `order`-th smallest of those values (up to order - 1 damaged values among them do not
    lower it). Delays only ever raise a stamp and a clock step moves all later ones: stamps below
    the floors on both sides are damage. The neighbourhoods are whole sub-blocks of w / 4 values,
    the value's own sub-block left out, so a run of damaged values is found as well as a lone one.
    The tolerance grows with the delays: the order-th smallest of w exponential delays exceeds
    c/w of their mean once in a thousand (``_poisson_quantile``), so a good stamp is rarely below
    both floors by more. The test is repeated with the damage found left out of the floors, until
    nothing new is found."""
    n = len(y)
    if n < 3:
        return np.zeros(n, dtype=bool)
    w = max(1, min(int(w), n))
    q = max(1, w // DAMAGE_SUBBLOCKS)  # values per sub-block
    side = -(-w // q)  # sub-blocks per neighbourhood
    k = max(1, min(int(order), side * q))
    kk = min(k, q)  # of each sub-block, the kk smallest can hold a neighbourhood's k smallest
    nsb = -(-n // q)
    step = max(1, DAMAGE_BLOCK // q) * q  # values per pass through the series: whole sub-blocks
    bad = np.zeros(n, dtype=bool)
    limit = None
    for _ in range(DAMAGE_SWEEPS):
        small = np.empty((nsb, kk))
        for a in range(0, n, step):  # a day's stamps without day-long temporaries
            v = np.where(bad[a:a + step], np.inf, y[a:a + step])
            v = np.concatenate([v, np.full(-len(v) % q, np.inf)]).reshape(-1, q)
            small[a // q:a // q + len(v)] = np.partition(v, kk - 1, axis=1)[:, :kk] if kk < q else v
        pad = np.full((side, kk), np.inf)
        near = np.lib.stride_tricks.sliding_window_view(np.concatenate([pad, small, pad]), side, axis=0)
        near = np.partition(near.reshape(len(near), -1), k - 1, axis=1)[:, k - 1]  # sub-blocks i..i+side-1
        floor = np.minimum(near[:nsb], near[side + 1:])  # the side sub-blocks before and after each
        del near
        if limit is None:
            delays = np.empty(n)
            m = 0
            for a in range(0, n, step):
                f = np.repeat(floor[a // q:(a + step) // q], q)[:min(step, n - a)]
                ok = np.isfinite(f)
                d = np.maximum(y[a:a + step][ok] - f[ok], 0.0)
                delays[m:m + len(d)] = d
                m += len(d)
            mean_delay = float(np.median(delays[:m], overwrite_input=True)) / np.log(2.0) if m else 0.0
            del delays
            limit = max(tol, _poisson_quantile(k) * mean_delay / w)
        new = np.zeros(n, dtype=bool)
        for a in range(0, n, step):
            f = np.repeat(floor[a // q:(a + step) // q], q)[:min(step, n - a)]
            new[a:a + step] = (y[a:a + step] < f - limit) & ~bad[a:a + step]
        if not new.any():
            break
        bad |= new
    return bad


SLOPE_BLOCK = 1 << 18  # points per block of _median_slope: a day's IMU stamps without day-long temporaries


def _median_slope(x: np.ndarray, y: np.ndarray, span: float) -> float:
    """Median of the slopes between each point and the first one at least `span` later in x
    (x ascending), worked out block by block into one array of slopes."""
    n = len(x)
    slopes = np.empty(n)
    m = 0
    for a in range(0, n, SLOPE_BLOCK):
        j = np.searchsorted(x, x[a:a + SLOPE_BLOCK] + span)
        i = np.flatnonzero(j < n)
        j = j[i]
        i += a
        slopes[m:m + len(i)] = (y[j] - y[i]) / (x[j] - x[i])
        m += len(i)
    if not m:
        i, j = np.argmin(x), np.argmax(x)
        return float((y[j] - y[i]) / (x[j] - x[i])) if x[j] > x[i] else 1.0
    return float(np.median(slopes[:m], overwrite_input=True))


def _steps(values: np.ndarray, threshold_s: float, window: int = GPS_WINDOW) -> tuple[np.ndarray, float]:
    """Indices i where the floor of `values` (a clock offset plus non-negative delays, slope
    removed) moves by more than the threshold and stays: the minimum of the window from i
    on against the minimum of the window before it. An upward step is found at the start of
    the run where the difference is large, a downward one at its end. Also returns the
    threshold used (raised when the delays are large)."""
    left, right = _running_min(values, window)
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


def _spurious_steps(x: np.ndarray, cuts: list, steps: list[float], threshold: float) -> set[int]:
    """Cuts that are not clock steps: one whose fitted size is below the threshold (the floor
    only looked different), or an upward step undone by a downward one of the same size within
    STALL_MAX_S: a host stall longer than the window, not two clock steps."""
    small = [i for i, d in enumerate(steps) if abs(d) < threshold]
    if small:
        return {min(small, key=lambda i: abs(steps[i]))}
    for i in range(len(steps) - 1):
        up, down = steps[i], steps[i + 1]
        if up > 0 > down and abs(up + down) < max(threshold, 0.1 * up) and x[cuts[i + 1]] - x[cuts[i]] < STALL_MAX_S:
            return {i, i + 1}
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
    rate0 = _median_slope(x[good][order], s[good][order], min(10.0, 0.25 * np.ptp(x[good])))
    if not np.isfinite(rate0) or rate0 <= 0:
        raise AlignmentError(f"the GPS stamps do not advance with GPS time (rate {rate0:.3g}): the ID 23 stamps "
                             f"or times of week are unusable")
    lag = s - rate0 * x
    damaged = ~good
    # The tolerance is what a damaged stamp left in may cost in GPS time: served S times faster,
    # a system second is S GPS seconds.
    damaged[good] = _damaged_low(lag[good], GPS_WINDOW, OUTLIER_TOL_S * rate0, 1 + GPS_WINDOW // DAMAGE_SHARE)
    keep = np.flatnonzero(~damaged)
    if len(keep) < 3:
        raise AlignmentError(f"only {len(keep)} GPS measurement blocks have a usable stamp")
    found, threshold = _steps(lag[keep], step_threshold_s)
    cuts = list(keep[found])
    while True:
        off_a, rate_a, steps = _fit_segments(x, s, keep, cuts, rate0)
        drop = _spurious_steps(x, cuts, steps, threshold)
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
    n = _counter_steps(c)
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


def _counter_steps(counter: np.ndarray) -> np.ndarray:
    step = np.diff(np.asarray(counter, dtype=np.int64)) % 256
    step[step == 0] = 256
    return np.concatenate([[0], np.cumsum(step)])


def _median_ahead(x: np.ndarray, m: int = MEDIAN_FRAMES) -> np.ndarray:
    """Median of x[i:i+m] for every i (fewer at the end)."""
    n = len(x)
    if n == 0:
        return x
    win = np.lib.stride_tricks.sliding_window_view(np.concatenate([x, np.full(m - 1, x[-1])]), m)
    return np.median(win, axis=1)


def _coarse_cut(clock: ClockMap, k: int, stamps: np.ndarray, lo: int) -> int:
    """First IMU record after the step between clock segments k-1 and k, to within a second
    or so: enough to count counter periods across gaps. Searched from record `lo` on. A frame
    counts only when the median of it and the next few agrees (one damaged stamp cannot)."""
    s = stamps[lo:]
    if not len(s):
        return lo
    delta = clock.steps_s[k - 1] / clock.rate[k]  # in GPS seconds
    a, b = clock.step_after[k - 1], clock.step_before[k - 1]
    pre = clock.to_gps(s, k - 1)
    post = clock.to_gps(s, k)
    pre_ahead, post_ahead = _median_ahead(pre), _median_ahead(post)
    m = MEDIAN_FRAMES
    behind = np.concatenate([np.full(m, np.nan), pre_ahead[:-m]]) if len(pre) > m else np.full(len(pre), np.nan)
    if delta >= 0:
        # Frames before the step read at least delta early on the new map (but a stretch
        # without ID 23 leaves frames before the step that pass); a large step is also a
        # jump on the old map, where the new map puts the frame near the step.
        hit = np.flatnonzero((post >= a) & (post_ahead >= a))
        if delta >= 1.0:
            with np.errstate(invalid="ignore"):
                jump = np.flatnonzero((pre - behind > 0.5 * delta) & (pre_ahead - behind > 0.5 * delta)
                                      & (behind >= a - MARGIN_S) & (post <= b + MARGIN_S) & (post >= a))
            if len(jump):
                hit = jump[:1]
    else:
        # After a backward step the old map reads |delta| early: a drop, or (when the IMU
        # was silent across the step) the first frame past the step on the old map.
        hit = np.flatnonzero((pre >= b) & (pre_ahead >= b))
        if abs(delta) >= 1.0:
            with np.errstate(invalid="ignore"):
                drop = np.flatnonzero((behind - pre > 0.5 * abs(delta)) & (behind - pre_ahead > 0.5 * abs(delta))
                                      & (behind <= b + MARGIN_S) & (post_ahead >= a - MARGIN_S))
            if len(drop):
                hit = np.sort(np.concatenate([hit, drop[:1]]))
    return lo + int(hit[0]) if len(hit) else lo + len(s)


def _ambiguous_span(clock: ClockMap, k: int, stamps: np.ndarray, lo: int, hi: int, coarse: int, margin: int
                    ) -> tuple[int, int]:
    """IMU records [a, b) that may lie on either side of step k: every frame whose true time can
    be within a margin of the GPS blocks around the step (a stretch without ID 23 widens it)
    on either map, which read |step| apart. Bounded by the neighbouring cuts [lo, hi]."""
    delta = abs(clock.steps_s[k - 1] / clock.rate[k]) + MARGIN_S
    sl = slice(lo, hi)
    early = _median_ahead(clock.to_gps(stamps[sl], k - 1)) >= clock.step_after[k - 1] - delta
    late = _median_ahead(clock.to_gps(stamps[sl], k)) >= clock.step_before[k - 1] + delta
    a = lo + (int(np.argmax(early)) if early.any() else hi - lo)
    b = lo + (int(np.argmax(late)) if late.any() else hi - lo)
    return max(lo, min(a, coarse) - margin), min(hi, max(b, coarse) + margin)


def _refine_cut(clock: ClockMap, k: int, stamps: np.ndarray, n: np.ndarray, period: float, lo: int, hi: int,
                usable: np.ndarray) -> int:
    """The cut in [lo, hi] that makes the IMU clock's floor tightest: frames before it on map k-1,
    the rest on map k, t - P n must be a constant plus non-negative delays. This is the lower
    envelope's objective (summed residuals above the floor) with the cut as a free variable."""
    idx = np.arange(lo, hi)
    idx = idx[usable[lo:hi]]
    if len(idx) == 0:
        return lo
    u = clock.to_gps(stamps[idx], k - 1) - period * n[idx]
    v = clock.to_gps(stamps[idx], k) - period * n[idx]
    m = len(idx)
    pre_min = np.concatenate([[np.inf], np.minimum.accumulate(u)])  # min u[:j]
    suf_min = np.concatenate([np.minimum.accumulate(v[::-1])[::-1], [np.inf]])  # min v[j:]
    total = np.concatenate([[0.0], np.cumsum(u)]) + np.concatenate([np.cumsum(v[::-1])[::-1], [0.0]])
    floor = np.minimum(pre_min, suf_min)
    cost = total - m * floor
    j = int(np.argmin(cost))
    return int(idx[j]) if j < m else hi


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
    damaged_gps_stamps: int = 0
    damaged_imu_stamps: int = 0
    pieces: int = 1  # stretches of the IMU clock fitted on their own
    step_times: list[float] = field(default_factory=list)  # GPS time of each clock step
    warnings: list[str] = field(default_factory=list)

    def gap_list(self, min_s: float = 0.0) -> list[dict]:
        """IMU gaps with their GPS times: [{t_before, t_after, frames_missing}]."""
        out = []
        for i, missing in self.gaps:
            if self.imu_t[i] - self.imu_t[i - 1] >= min_s:
                out.append({"t_before": float(self.imu_t[i - 1]), "t_after": float(self.imu_t[i]),
                            "frames_missing": int(missing)})
        return out

    def summary(self) -> dict:
        def pct(x):
            x = x[np.isfinite(x)]
            return {k: float(np.percentile(x, p)) for k, p in (("median", 50), ("p99", 99), ("max", 100))} \
                if len(x) else {}
        return {"method": self.method, "week": self.week, "imu_samples": int(len(self.imu_t)),
                "imu_frames_missing": int(sum(g[1] for g in self.gaps)), "gaps": len(self.gaps),
                "gaps_longer_than_1_s": self.gap_list(1.0),
                "imu_period_s": self.imu_period_s, "imu_clock_ppm": self.imu_clock_ppm,
                "clock_steps_s": self.steps_s, "clock_step_times": self.step_times,
                "damaged_stamps": {"gps": self.damaged_gps_stamps, "imu": self.damaged_imu_stamps},
                "imu_clock_pieces": self.pieces,
                "gps_stamp_residual_s": pct(self.gps_residual_s),
                "imu_stamp_residual_s": pct(self.imu_residual_s), "warnings": self.warnings}


def _fit_imu_clock(n: np.ndarray, mapped: np.ndarray, usable: np.ndarray, period: float, piece_gap_frames: int
                   ) -> tuple[np.ndarray, float, int]:
    """t = t0 + P n per stretch between long gaps, along the lower envelope of the usable frames."""
    breaks = np.flatnonzero(np.diff(n) > piece_gap_frames) + 1
    bounds = list(zip(np.concatenate([[0], breaks]), np.concatenate([breaks, [len(n)]])))
    fits: list[tuple[float, float] | None] = []
    spans = []
    for a, b in bounds:
        u = n[a:b][usable[a:b]]
        span = (u[-1] - u[0]) * period if len(u) else 0.0
        x = u.astype(float) if span >= MIN_RATE_SPAN_S else None
        del u
        fits.append(lower_envelope(x, mapped[a:b][usable[a:b]]) if x is not None else None)
        spans.append(span)
        del x
    long = [i for i, f in enumerate(fits) if f is not None]
    if long:
        p = float(sum(fits[i][1] * spans[i] for i in long) / sum(spans[i] for i in long))
    else:
        k = np.flatnonzero(usable)
        p = lower_envelope(n[k].astype(float), mapped[k])[1] if len(k) >= 2 and np.ptp(n[k]) > 0 else period
        # One pooled line cannot hold several stretches with their own phases: keep P only.
    t = np.empty(len(n))
    for (a, b), f in zip(bounds, fits):
        if f is None:
            k = np.flatnonzero(usable[a:b]) + a
            ref = k if len(k) else np.arange(a, b)
            t0 = float(np.min(mapped[ref] - p * n[ref]))
            t[a:b] = t0 + p * n[a:b]
        else:
            t[a:b] = f[0] + f[1] * n[a:b]
    return t, p, len(bounds)


def align(gps_tow: np.ndarray, gps_stamps: np.ndarray, week: int, imu_stamps: np.ndarray, imu_counter: np.ndarray,
          rate_hz: float, *, method: str = "robust", gps_latency_s: float = 0.0, imu_latency_s: float = 0.0,
          step_threshold_s: float = 0.01) -> Alignment:
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

    warnings: list[str] = []
    clock = fit_gps_clock(gps_tow, gps_stamps, gps_latency_s, step_threshold_s)
    s = imu_stamps - imu_latency_s
    if not np.all(np.isfinite(s)):
        raise AlignmentError(f"{int(np.sum(~np.isfinite(s)))} IMU stamps are not finite numbers")
    # A map fitted on the GPS stamps says nothing about system times far outside them.
    g = np.asarray(gps_stamps, dtype=float)
    g = g[np.isfinite(g)]
    imu_lo, imu_hi = np.percentile(s, [1, 99])
    if imu_hi < g.min() - OVERLAP_SLACK_S or imu_lo > g.max() + OVERLAP_SLACK_S:
        raise AlignmentError(f"the IMU stamps (system time {imu_lo:.1f} to {imu_hi:.1f} s) do not overlap the GPS "
                             f"stamps ({g.min():.1f} to {g.max():.1f} s): the two files were not recorded together")
    # Damaged IMU stamps: far below both neighbourhoods once the counter's trend is removed.
    nc = _counter_steps(imu_counter)
    w = max(8, int(IMU_WINDOW_S * rate_hz))
    # (Slopes over at most 10 s, as for the frame period below: over longer spans, the pairs that
    # straddle a gap the counter cannot count or a clock step bias it, and its residual slope
    # shows in the floors beside a step.)
    trend = (_median_slope(nc.astype(float), s, max(1.0, min(0.25 * float(np.ptp(nc)), 10.0 * rate_hz)))
             if np.ptp(nc) > 0 else period)
    usable = ~_damaged_low(s - trend * nc, w, OUTLIER_TOL_S * float(clock.rate[0]), 1 + w // DAMAGE_SHARE)

    # Stage 2: each clock step's cut in the IMU stream, coarse first.
    n_seg = len(clock.starts)
    cuts = []
    lo = 0
    for k in range(1, n_seg):
        lo = _coarse_cut(clock, k, s, lo)
        cuts.append(lo)
    seg = np.searchsorted(np.array(cuts, dtype=np.int64), np.arange(len(s)), side="right") if cuts else 0
    mapped = clock.to_gps(s, seg)
    # The frame period as the stamps show it: a configured rate that is wrong would count
    # the wrong number of counter periods across a gap.
    if np.ptp(nc) > 0:
        seen = _median_slope(nc.astype(float), mapped, min(0.25 * float(np.ptp(nc)), 10.0 * rate_hz))
        if abs(seen * rate_hz - 1.0) > RATE_MISMATCH:
            warnings.append(f"the IMU frames come at {1.0 / seen:.2f} Hz, not the configured {rate_hz:g} Hz: "
                            f"the stamps' rate is used")
            period = seen
    # Stage 3: sample indices against the mapped times (immune to the clock steps).
    n = unwrap_counter(imu_counter, mapped, period, usable, int(UNWRAP_WINDOW_S / period))
    if cuts:
        refined = []
        for k, c in enumerate(cuts, start=1):
            a, b = _ambiguous_span(clock, k, s, refined[-1] if refined else 0,
                                   cuts[k] if k < len(cuts) else len(s), c, int(2.0 / period))
            refined.append(_refine_cut(clock, k, s, n, period, a, b, usable) if b > a else c)
        cuts = refined
        seg = np.searchsorted(np.array(cuts, dtype=np.int64), np.arange(len(s)), side="right")
        mapped = clock.to_gps(s, seg)
        n = unwrap_counter(imu_counter, mapped, period, usable, int(UNWRAP_WINDOW_S / period))
    # Stage 4: the IMU clock (the stamps and counter steps no longer needed: a day of them is 90 MB).
    del s, nc
    # With the gaps counted and the clock steps taken out, the mapped times less the counter's
    # are one flat series (GPS seconds): damage right beside a gap or a step, which the test on the
    # stamps could only compare with one side, shows here.
    if np.ptp(n) > 0:
        flat = _median_slope(n.astype(float), mapped, max(1.0, min(0.25 * float(np.ptp(n)), 10.0 * rate_hz)))
        usable &= ~_damaged_low(mapped - flat * n, w, OUTLIER_TOL_S, 1 + w // DAMAGE_SHARE)
    t, p, pieces = _fit_imu_clock(n, mapped, usable, period, int(PIECE_GAP_S / period))
    if np.any(np.diff(t) <= 0):
        i = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise AlignmentError(f"IMU record {i}: its time does not follow record {i - 1} after alignment "
                             f"({t[i - 1]:.3f} -> {t[i]:.3f} s); the IMU stamps are inconsistent with its counter")
    jumps = np.flatnonzero(np.diff(n) > 1)
    gaps = [(int(j + 1), int(n[j + 1] - n[j] - 1)) for j in jumps]
    n_gps_bad = int(clock.damaged.sum())
    n_imu_bad = int((~usable).sum())
    if n_gps_bad:
        warnings.append(f"{n_gps_bad} GPS stamp(s) far below their neighbours left out of the clock fit (damaged)")
    if n_imu_bad:
        warnings.append(f"{n_imu_bad} IMU stamp(s) far below their neighbours left out of the clock fit (damaged)")
    # Far too late for a delay (no host holds frames this long without losing them): damaged too,
    # harmless to the fits, which follow the floor.
    late = {"GPS": int(np.sum(clock.residual_s > LATE_S)), "IMU": int(np.sum(mapped - t > LATE_S))}
    for name, count in late.items():
        if count:
            warnings.append(f"{count} {name} stamp(s) more than {LATE_S:g} s late (damaged), ignored")
    step_times = [float(x) for x in clock.step_before]
    for dt, at in zip(clock.steps_s, step_times):
        warnings.append(f"realtime clock step of {dt:+.3f} s at GPS time {at:.1f} s")
    for g in [g for g in gaps if g[1] * p >= PIECE_GAP_S]:
        warnings.append(f"IMU gap of {g[1]} frames ({g[1] * p:.2f} s) before GPS time {t[g[0]]:.2f} s")
    return Alignment("robust", t, week, n, gaps, float(p), float((1.0 / (rate_hz * p) - 1.0) * 1e6), clock.residual_s,
                     mapped - t, clock.steps_s, n_gps_bad, n_imu_bad, pieces, step_times, warnings)
