"""The ionosphere from a second frequency: decoded L1 ranges in, L1 ranges without their ionospheric delay out.

A dual-frequency receiver measures each satellite's code on two carriers. The ionosphere delays a code by
I f1^2 / f^2 (first order), so with gamma = (f1 / f2)^2 the two codes differ by

    P2 - P1 = (gamma - 1) (I1 + c TGD) + receiver bias,

TGD the satellite's broadcast group delay of that pair (GPS: TGD of L1/L2 P(Y), IS-GPS-200 20.3.3.3.3.2;
Galileo: BGD(E1, E5a), OS SIS ICD 5.1.5) and the receiver's own inter-frequency bias common to every
satellite of a system (the receiver clock, and for Galileo the differencing, take it). The L1 user's
clock correction already carries the single-frequency TGD, so the L1 range less I1 goes through the
filter's L1 model unchanged; only the broadcast (Klobuchar) ionosphere is left out.

Code on the second carrier is noisier and the geometry-free difference multiplies it by about 1.3-1.6,
while the ionosphere moves by centimetres per minute: each satellite's I1 is averaged along its track
(a running mean for the first ``smoothing_s``, then an exponential average with that time constant), and
a track starts again after ``max_gap_s`` (or three of the file's intervals) without both codes. Code
multipath that lasts longer than the smoothing stays in, amplified: a hand-held antenna standing still
keeps steps of 2-3 m in the geometry-free code for tens of seconds (the walk data set).

An L1 range without a second code in its epoch has no measured ionosphere: it is dropped (counted), since
mixing corrected and uncorrected ranges would bias the position by the delay of the uncorrected ones.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from .. import _core, lazy
from ..formats.common import Navigation, Pseudoranges
from ..formats.galileo_inav import GALILEO_ID_OFFSET

lfilter = lazy.name("scipy.signal", "lfilter")  # 0.6 s of imports a replay without dual frequency never uses

F_L1_HZ = 1575.42e6  # GPS L1 and Galileo E1
F_SECOND_HZ = {"gps": 1227.60e6, "galileo": 1176.45e6}  # GPS L2, Galileo E5a: what readers give as second
SMOOTHING_S = 60.0
MAX_GAP_S = 10.0


def gamma(system: str) -> float:
    return (F_L1_HZ / F_SECOND_HZ[system]) ** 2


def group_delays_s(nav: Navigation, sat_ids: np.ndarray) -> np.ndarray:
    """The pair's group delay per row: GPS TGD, Galileo BGD(E1, E5a); the latest broadcast of each satellite
    (both change rarely), 0 where none was decoded."""
    tgd = {e.prn: e.tgd_s for e in nav.ephemerides if e.prn <= GALILEO_ID_OFFSET}
    tgd.update(nav.bgd_e1_e5a_s)
    return np.array([tgd.get(int(i), 0.0) for i in sat_ids])


def _smooth(t: np.ndarray, x: np.ndarray, smoothing_s: float) -> np.ndarray:
    """Running mean over the first smoothing_s of a track, exponential average after it."""
    dt = float(np.median(np.diff(t))) if len(t) > 1 else smoothing_s
    n_full = max(1, int(round(smoothing_s / max(dt, 1e-3))))
    out = np.cumsum(x) / np.arange(1, len(x) + 1)
    if len(x) > n_full:
        a = 1.0 / n_full
        out[n_full:] = lfilter([a], [1.0, a - 1.0], x[n_full:], zi=[(1.0 - a) * out[n_full - 1]])[0]
    return out


def l1_delay_m(l1: Pseudoranges, second: Pseudoranges, nav: Navigation, smoothing_s: float = SMOOTHING_S,
               max_gap_s: float = MAX_GAP_S) -> np.ndarray:
    """Each L1 row's smoothed ionospheric delay (metres), NaN where its epoch has no second code."""
    key2 = {(t, p): i for i, (t, p) in enumerate(zip(second.t_abs.tolist(), second.prn.tolist()))}
    j = np.array([key2.get(k, -1) for k in zip(l1.t_abs.tolist(), l1.prn.tolist())], dtype=int)
    paired = np.flatnonzero(j >= 0)
    out = np.full(len(l1), np.nan)
    if not len(paired):
        return out
    prn = l1.prn[paired]
    g = np.where(prn > GALILEO_ID_OFFSET, gamma("galileo"), gamma("gps"))
    raw = (second.pr_m[j[paired]] - l1.pr_m[paired]) / (g - 1.0) \
        - _core.gnss.SPEED_OF_LIGHT * group_delays_s(nav, prn)
    t = l1.t_abs[paired]
    epochs = np.unique(t)
    # A track breaks at a gap, not at the file's own interval (30 s RINEX).
    gap_s = max(max_gap_s, 3.0 * float(np.median(np.diff(epochs)))) if len(epochs) > 1 else max_gap_s
    for sat in np.unique(prn):
        rows = np.flatnonzero(prn == sat)  # in time order: the table's epochs are
        starts = np.flatnonzero(np.diff(t[rows]) > gap_s) + 1
        for track in np.split(rows, starts):
            out[paired[track]] = _smooth(t[track], raw[track], smoothing_s)
    return out


def corrected(l1: Pseudoranges, second: Pseudoranges, nav: Navigation, smoothing_s: float = SMOOTHING_S,
              max_gap_s: float = MAX_GAP_S) -> tuple[Pseudoranges, Counter]:
    """L1 ranges less their smoothed dual-frequency delay; rows without a second code left out (counted)."""
    delay = l1_delay_m(l1, second, nav, smoothing_s, max_gap_s)
    keep = np.isfinite(delay)
    out = l1.select(keep)
    out.pr_m = out.pr_m - delay[keep]
    dropped = Counter()
    if (~keep).any():
        dropped["pseudoranges without a second frequency (dual-frequency ionosphere)"] = int((~keep).sum())
    return out, dropped
