"""GPS time for every IMU sample (``align``): the IMU's clock fitted through the GPS clock map, cut
where the IMU's clock restarts, with what it found (``Alignment``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from . import (AlignmentError, DAMAGE_SHARE, IMU_WINDOW_S, LATE_S, MARGIN_S, MEDIAN_FRAMES, METHODS, MIN_RATE_SPAN_S,
               OUTLIER_TOL_S, OVERLAP_SLACK_S, PIECE_GAP_S, RATE_MISMATCH, UNWRAP_WINDOW_S)
from .clock import ClockMap, counter_steps, fit_gps_clock, unwrap_counter
from .envelope import damaged_low, median_slope, lower_envelope


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
    nc = counter_steps(imu_counter)
    w = max(8, int(IMU_WINDOW_S * rate_hz))
    # (Slopes over at most 10 s, as for the frame period below: over longer spans, the pairs that
    # straddle a gap the counter cannot count or a clock step bias it, and its residual slope
    # shows in the floors beside a step.)
    trend = (median_slope(nc.astype(float), s, max(1.0, min(0.25 * float(np.ptp(nc)), 10.0 * rate_hz)))
             if np.ptp(nc) > 0 else period)
    usable = ~damaged_low(s - trend * nc, w, OUTLIER_TOL_S * float(clock.rate[0]), 1 + w // DAMAGE_SHARE)

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
        seen = median_slope(nc.astype(float), mapped, min(0.25 * float(np.ptp(nc)), 10.0 * rate_hz))
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
        flat = median_slope(n.astype(float), mapped, max(1.0, min(0.25 * float(np.ptp(n)), 10.0 * rate_hz)))
        usable &= ~damaged_low(mapped - flat * n, w, OUTLIER_TOL_S, 1 + w // DAMAGE_SHARE)
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
