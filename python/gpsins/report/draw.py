"""Drawing helpers of the report's figures: segment marks, bands, legends, broken lines, and axis limits
that follow the bulk of the data with the values beyond them marked at the edge.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .. import lazy
from .data import AXIS_STYLES, Result


plt = lazy.module("matplotlib.pyplot", before=lazy.agg_backend)
Line2D = lazy.name("matplotlib.lines", "Line2D", before=lazy.agg_backend)
Patch = lazy.name("matplotlib.patches", "Patch", before=lazy.agg_backend)
chi2 = lazy.name("scipy.stats", "chi2")

BAND_ALPHA = 0.15
EDGE_GID = "beyond-axis"
GAP_S = 2.5  # samples further apart are not joined by a line


class TimeAxis(NamedTuple):
    """Where every time axis counts from (results' time) and the label that says so."""

    t0: float
    label: str


def mark_segments(axs, base: Result, t0: float, letters: bool = True) -> None:
    """Segment starts as faint vertical lines on every time axis, their letters on the top one."""
    if "seg_t" not in base.a:
        return
    for j, ax in enumerate(axs):
        for label, (s0, _) in zip(base.a["seg_labels"], base.a["seg_t"]):
            ax.axvline(s0 - t0, color="0.6", lw=0.5, ls=":", zorder=0)
            if j == 0 and letters:
                ax.text(s0 - t0, 1.01, str(label).split("-")[0], transform=ax.get_xaxis_transform(), fontsize=7,
                        ha="center", va="bottom", color="0.35")


def band_handles(results, alpha: float = BAND_ALPHA) -> list:
    """One swatch per run drawn like its band (the run's colour and the band's alpha)."""
    return [Patch(facecolor=r.color, alpha=alpha, lw=0, label=f"{r.name} 3-sigma") for r in results]


def mode_handles(results, band: bool = False, alpha: float = BAND_ALPHA) -> list:
    h = [Line2D([], [], color=r.color, lw=1.2, label=r.name) for r in results]
    return h + (band_handles(results, alpha) if band else [])


def axis_handles(names=("north", "east", "down")) -> list:
    return [Line2D([], [], color="k", ls=ls, lw=1, label=n) for ls, n in zip(AXIS_STYLES, names)]


def beyond_handle() -> Line2D:
    return Line2D([], [], color="k", marker="^", ls="", label="beyond the axis (at its edge)")


def sigma_band(ax, t, s, color, alpha=BAND_ALPHA):
    ax.fill_between(t, -3 * s, 3 * s, color=color, alpha=alpha, lw=0)


def _broken(t: np.ndarray, y: np.ndarray, cut_after: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A NaN after every sample where cut_after is true: the line is not drawn across."""
    cut = np.flatnonzero(cut_after) + 1
    return np.insert(np.asarray(t, float), cut, np.nan), np.insert(np.asarray(y, float), cut, np.nan)


def gapped(t: np.ndarray, y: np.ndarray, gap_s: float = GAP_S) -> tuple[np.ndarray, np.ndarray]:
    """Break a line where the samples are further apart than gap_s (no bridges across outages)."""
    return _broken(t, y, np.diff(t) > gap_s)


def wrap_broken(t: np.ndarray, deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Break an angle's line where it wraps (a step over half a turn), not draw a vertical across the axis."""
    return _broken(t, deg, np.abs(np.diff(deg)) > 180.0)


def bound(ax, t: np.ndarray, s3: np.ndarray, color) -> None:
    """+-3 sigma as lines broken at gaps, and a tick at each update with no neighbour to draw a line to."""
    for sgn in (1, -1):
        ax.plot(*gapped(t, sgn * s3), "-", color=color, lw=0.6)
    far = np.diff(t) > GAP_S
    lone = np.r_[True, far] & np.r_[far, True]
    if lone.any():
        ax.plot(np.r_[t[lone], t[lone]], np.r_[s3[lone], -s3[lone]], "_", color=color, ms=7, mew=0.8, ls="")


def clip_limit(values: np.ndarray, bounds: np.ndarray) -> float:
    """A symmetric y limit showing the usual values and bounds; outliers are marked at the edge."""
    v, b = np.abs(values[np.isfinite(values)]), np.abs(bounds[np.isfinite(bounds)])
    if len(v) == 0 and len(b) == 0:
        return 1.0
    lim = max(np.percentile(v, 99) if len(v) else 0.0, 2.0 * np.median(b) if len(b) else 0.0)
    return 1.2 * lim if lim > 0 else 1.0


def log_limits(values: np.ndarray, keep: tuple[float, float]) -> tuple[float, float]:
    """A log y range for the bulk of the values that still shows `keep` (a band): one value near 0 would
    otherwise squash the rest into a line. The bulk: within three interquartile ranges of the quartiles
    of log10 (Tukey's far-out fences), which a few outliers do not move."""
    v = values[np.isfinite(values) & (values > 0)]
    lo, hi = keep
    if len(v):
        q1, q3 = np.percentile(np.log10(v), [25, 75])
        fence = 3.0 * (q3 - q1)
        lo = min(lo, max(v.min(), 10 ** (q1 - fence)))
        hi = max(hi, min(v.max(), 10 ** (q3 + fence)))
    return lo / 2, hi * 2


def mark_beyond(ax, t, y, lo: float, hi: float, color, points: bool = False) -> bool:
    """A triangle at the axis edge for each stretch of values beyond [lo, hi] (each value, for `points`),
    at the stretch's extreme; returns whether any were drawn."""
    t, y = np.asarray(t, float), np.asarray(y, float)
    drawn = False
    with np.errstate(invalid="ignore"):
        sides = ((y > hi, "^", 0.975, np.argmax), (y < lo, "v", 0.025, np.argmin))
    for out, marker, edge, extreme in sides:
        idx = np.flatnonzero(out)
        if len(idx) == 0:
            continue
        runs = np.split(idx, np.arange(1, len(idx)) if points else np.flatnonzero(np.diff(idx) > 1) + 1)
        at = [run[extreme(y[run])] for run in runs]
        ax.plot(t[at], np.full(len(at), edge), marker, color=color, ms=5, ls="", gid=EDGE_GID,
                transform=ax.get_xaxis_transform(), zorder=6)  # above a legend box (5): never hidden
        drawn = True
    return drawn


def limit_and_mark(ax, lo: float, hi: float, series) -> bool:
    """Set the y limits and mark what of each series ((t, y, colour, points) each) they leave out;
    returns whether anything was."""
    ax.set_ylim(lo, hi)
    marked = [mark_beyond(ax, t, y, lo, hi, c, points) for t, y, c, points in series]
    return any(marked)
