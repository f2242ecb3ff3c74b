"""Lower envelopes of delayed stamps, running minima, damaged stamps and median slopes: the robust
statistics the clock fits are made of.
"""

from __future__ import annotations

import math

import numpy as np
from . import AlignmentError


HULL_BLOCK = 1 << 16  # points per block of a long series' lower hull


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


def running_min(y: np.ndarray, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Minimum of the w values before i (i excluded) and of the w values from i on; inf where empty."""
    n = len(y)
    w = max(1, min(int(w), n))
    pad = np.full(w, np.inf)
    m = _window_min(np.concatenate([pad, y, pad]), w)  # m[j] = min over padded[j : j + w]
    return m[:n], m[w:w + n]


DAMAGE_BLOCK = 1 << 18  # values per block of damaged_low
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


def damaged_low(y: np.ndarray, w: int, tol: float, order: int = 1) -> np.ndarray:
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


SLOPE_BLOCK = 1 << 18  # points per block of median_slope: a day's IMU stamps without day-long temporaries


def median_slope(x: np.ndarray, y: np.ndarray, span: float) -> float:
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
