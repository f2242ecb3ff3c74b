"""Stamp plausibility: the span a session's stamps may take (from its sidecar: start, stop, clock pairs),
and stamps out of line with their neighbours, rejected with their records.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gpsins_logger.recorder import CLOCK_STEP_THRESHOLD_S
from .layouts import SPAN_MARGIN_S, STAMP_MAX, STAMP_MIN, Scan


@dataclass(frozen=True)
class StampLimits:
    """What a plausible stamp is for one session: inside [lo, hi], and never
    earlier than a neighbouring record's stamp by more than back_s (a clock
    step the clock pairs saw, or the logger's clamp tolerance)."""

    lo: float = STAMP_MIN
    hi: float = STAMP_MAX
    back_s: float = CLOCK_STEP_THRESHOLD_S


def stamp_limits(directory: Path, sidecar: dict) -> StampLimits:
    """The session's span from the sidecar's start/stop and the clock pairs,
    widened by a margin; a session without a stop (the logger was killed) may
    have records up to a clock-pair interval after the last pair. Between two
    pairs the realtime clock may have stepped at any moment, so each interval
    spans its monotonic length under either pair's offset."""
    pairs = []
    for key in ("start", "stop"):
        pair = sidecar.get(key)
        if isinstance(pair, dict) and _finite(pair.get("realtime")):
            m = pair.get("monotonic")
            pairs.append((float(pair["realtime"]), float(m) if _finite(m) else np.nan))
    try:
        with open(directory / "clock.csv", encoding="ascii", errors="replace") as f:
            next(f, None)
            for line in f:
                try:
                    r, m = (float(v) for v in line.split(","))
                except ValueError:
                    continue  # a torn last line
                if np.isfinite(r) and np.isfinite(m):
                    pairs.append((r, m))
    except OSError:
        pass
    if not pairs:
        return StampLimits()
    real = np.array([r for r, _ in pairs])
    lo, hi = float(real.min()), float(real.max())
    timed = np.array(sorted((m, r - m) for r, m in pairs if np.isfinite(m)))
    back = CLOCK_STEP_THRESHOLD_S
    if len(timed) > 1:
        mono, off = timed[:, 0], timed[:, 1]
        lo = min(lo, float(np.min(mono[:-1] + np.minimum(off[:-1], off[1:]))))
        hi = max(hi, float(np.max(mono[1:] + np.maximum(off[:-1], off[1:]))))
        back = max(back, -float(np.min(np.diff(off))) + CLOCK_STEP_THRESHOLD_S)
    interval = 0.0
    if not isinstance(sidecar.get("stop"), dict):
        cfg = sidecar.get("config", {}).get("session", {}) if isinstance(sidecar.get("config"), dict) else {}
        interval = float(cfg.get("clock_pair_interval_s", 10.0)) if _finite(cfg.get("clock_pair_interval_s", 10.0)) \
            else 10.0
    return StampLimits(lo - SPAN_MARGIN_S, hi + interval + SPAN_MARGIN_S, back)


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and bool(np.isfinite(v))


OUTLIER_ROWS = 1 << 20  # stamps compared at a time: the temporaries stay a few MB whatever the file


def stamp_outliers(st: np.ndarray, limits: StampLimits) -> np.ndarray:
    """Which stamps are impossible: outside the session, or out of line with both neighbours."""
    bad = ~((st >= limits.lo) & (st <= limits.hi))
    # Neighbour test on the records left: a stamp is damaged when it runs back
    # from the previous record or ahead of the next by more than a clock step,
    # while those two agree with each other. Repeat so a damaged record does
    # not hide its neighbour's damage; each pass only removes records.
    for _ in range(8):
        keep = np.flatnonzero(~bad) if bad.any() else None  # None: all of them, no copy
        t = st if keep is None else st[keep]
        if len(t) < 2:
            break
        out = _out_of_line(t, limits.back_s)
        if not out.any():
            break
        bad[out if keep is None else keep[out]] = True
    return bad


def _out_of_line(t: np.ndarray, back: float) -> np.ndarray:
    """One pass of the neighbour test over t, a block of rows at a time."""
    n = len(t)
    out = np.zeros(n, dtype=bool)
    for a in range(0, n, OUTLIER_ROWS):
        b = min(n, a + OUTLIER_ROWS)
        cur = t[a:b]
        prev = t[a - 1:b - 1] if a > 0 else np.concatenate(([-np.inf], t[:b - 1]))
        nxt = t[a + 1:b + 1] if b < n else np.concatenate((t[a + 1:], [np.inf]))
        agree = nxt >= prev - back
        # The ends have one neighbour: it must agree with its own other neighbour.
        if n < 3:
            agree[:] = False
        else:
            if a == 0:
                agree[0] = t[2] >= t[1] - back
            if b == n:
                agree[-1] = t[-2] >= t[-3] - back
        out[a:b] = ((cur < prev - back) | (cur > nxt + back)) & agree
    return out


def first_backwards(st: np.ndarray) -> tuple[int, int | None]:
    """How many stamps run back from the one before, and the index of the first."""
    count, first = 0, None
    for a in range(0, len(st) - 1, OUTLIER_ROWS):
        back = np.flatnonzero(st[a + 1:a + 1 + OUTLIER_ROWS] < st[a:a + OUTLIER_ROWS][:len(st) - 1 - a])
        count += len(back)
        if first is None and len(back):
            first = a + int(back[0]) + 1
    return count, first


def reject_bad_stamps(s: Scan, limits: StampLimits) -> Scan:
    """Drop records whose stamp is impossible (see :func:`stamp_outliers`),
    count them, keep their neighbours."""
    if not s.layout.stamped or not s.count:
        return s
    bad = stamp_outliers(s.stamps, limits)
    n_bad = int(np.count_nonzero(bad))
    if n_bad:
        s.stats["bad_stamps"] += n_bad
        first = int(s.starts[np.argmax(bad)])
        old = s.stats["first_bad_stamp_offset"]
        s.stats["first_bad_stamp_offset"] = first if old is None else min(old, first)
        s.stats["discarded_bytes"] += int(s.lengths[bad].sum())
        s.stats["records"] -= n_bad
        s.keep(~bad)
    return s
