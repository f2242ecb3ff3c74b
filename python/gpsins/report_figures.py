"""The report's figures (matplotlib Figure objects, so tests can inspect what each panel holds) and their
captions, from results ``report.load`` made. ``report`` builds the pages around them.

Every time axis counts from one origin, ``report.time_origin`` (the first GNSS epoch), the same as the
page's tables. An axis whose limits follow the bulk of the data marks what it leaves out with a triangle
at its edge (gid ``EDGE_GID``), one per stretch beyond it.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from . import _core, evaluate, lazy
from .report import (AXIS_STYLES, KIND_FIX2, KIND_FIX3, KIND_NAMES, KIND_PR, KIND_RR, RECEIVER_COLOR, SECONDS_PER_WEEK,
                     Result, SkyData, _truth_file, receiver_errors, sky_data, time_origin, time_origin_text,
                     true_residual_biases, truth_ecef)

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


# ---------------------------------------------------------------- drawing helpers


def _mark_segments(axs, base: Result, t0: float, letters: bool = True) -> None:
    """Segment starts as faint vertical lines on every time axis, their letters on the top one."""
    if "seg_t" not in base.a:
        return
    for j, ax in enumerate(axs):
        for label, (s0, _) in zip(base.a["seg_labels"], base.a["seg_t"]):
            ax.axvline(s0 - t0, color="0.6", lw=0.5, ls=":", zorder=0)
            if j == 0 and letters:
                ax.text(s0 - t0, 1.01, str(label).split("-")[0], transform=ax.get_xaxis_transform(), fontsize=7,
                        ha="center", va="bottom", color="0.35")


def _band_handles(results, alpha: float = BAND_ALPHA) -> list:
    """One swatch per run drawn like its band (the run's colour and the band's alpha)."""
    return [Patch(facecolor=r.color, alpha=alpha, lw=0, label=f"{r.name} 3-sigma") for r in results]


def _mode_handles(results, band: bool = False, alpha: float = BAND_ALPHA) -> list:
    h = [Line2D([], [], color=r.color, lw=1.2, label=r.name) for r in results]
    return h + (_band_handles(results, alpha) if band else [])


def _axis_handles(names=("north", "east", "down")) -> list:
    return [Line2D([], [], color="k", ls=ls, lw=1, label=n) for ls, n in zip(AXIS_STYLES, names)]


def _beyond_handle() -> Line2D:
    return Line2D([], [], color="k", marker="^", ls="", label="beyond the axis (at its edge)")


def _band(ax, t, s, color, alpha=BAND_ALPHA):
    ax.fill_between(t, -3 * s, 3 * s, color=color, alpha=alpha, lw=0)


def _broken(t: np.ndarray, y: np.ndarray, cut_after: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A NaN after every sample where cut_after is true: the line is not drawn across."""
    cut = np.flatnonzero(cut_after) + 1
    return np.insert(np.asarray(t, float), cut, np.nan), np.insert(np.asarray(y, float), cut, np.nan)


def _gapped(t: np.ndarray, y: np.ndarray, gap_s: float = GAP_S) -> tuple[np.ndarray, np.ndarray]:
    """Break a line where the samples are further apart than gap_s (no bridges across outages)."""
    return _broken(t, y, np.diff(t) > gap_s)


def _wrap_broken(t: np.ndarray, deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Break an angle's line where it wraps (a step over half a turn), not draw a vertical across the axis."""
    return _broken(t, deg, np.abs(np.diff(deg)) > 180.0)


def _bound(ax, t: np.ndarray, s3: np.ndarray, color) -> None:
    """+-3 sigma as lines broken at gaps, and a tick at each update with no neighbour to draw a line to."""
    for sgn in (1, -1):
        ax.plot(*_gapped(t, sgn * s3), "-", color=color, lw=0.6)
    far = np.diff(t) > GAP_S
    lone = np.r_[True, far] & np.r_[far, True]
    if lone.any():
        ax.plot(np.r_[t[lone], t[lone]], np.r_[s3[lone], -s3[lone]], "_", color=color, ms=7, mew=0.8, ls="")


def _clip_limit(values: np.ndarray, bounds: np.ndarray) -> float:
    """A symmetric y limit showing the usual values and bounds; outliers are marked at the edge."""
    v, b = np.abs(values[np.isfinite(values)]), np.abs(bounds[np.isfinite(bounds)])
    if len(v) == 0 and len(b) == 0:
        return 1.0
    lim = max(np.percentile(v, 99) if len(v) else 0.0, 2.0 * np.median(b) if len(b) else 0.0)
    return 1.2 * lim if lim > 0 else 1.0


def _log_limits(values: np.ndarray, keep: tuple[float, float]) -> tuple[float, float]:
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


def _mark_beyond(ax, t, y, lo: float, hi: float, color, points: bool = False) -> bool:
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


def _limit_and_mark(ax, lo: float, hi: float, series) -> bool:
    """Set the y limits and mark what of each series ((t, y, colour, points) each) they leave out;
    returns whether anything was."""
    ax.set_ylim(lo, hi)
    marked = [_mark_beyond(ax, t, y, lo, hi, c, points) for t, y, c, points in series]
    return any(marked)


# ---------------------------------------------------------------- figures


def _fig_trajectory(results, base, tx):
    origin = base.a["llh"][0]
    c = evaluate.c_en(np.array([origin[0]]), np.array([origin[1]]))[0]
    o = _core.geodetic_to_ecef(origin)
    fig, ax = plt.subplots(figsize=(7, 7))
    for r in results:
        ne = (r.a["r_ecef"] - o) @ c
        ax.plot(ne[:, 1], ne[:, 0], color=r.color, lw=1.2, label=f"{r.name} filter")
    f = base.a["fixes"]
    fne = (f[f[:, 9] > 0, 1:4] - o) @ c
    ax.plot(fne[:, 1], fne[:, 0], "o", mfc="none", color=RECEIVER_COLOR, ms=4, label="receiver fixes")
    lettered = False
    if base.has_truth:
        true_ne = (truth_ecef(base) - o) @ c
        ax.plot(true_ne[:, 1], true_ne[:, 0], "k--", lw=0.8, label="truth")
        for label, (s0, _) in zip(base.a.get("seg_labels", ()), base.a.get("seg_t", ())):
            k = np.searchsorted(base.a["t"], s0)
            if k < len(true_ne) and np.isfinite(true_ne[k, 0]):
                ax.annotate(str(label).split("-")[0], true_ne[k, [1, 0]], fontsize=8, color="k")
                lettered = True
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_aspect("equal", "datalim")
    ax.legend(loc="best", fontsize=8)
    ax.set_title("Trajectory" + (" (letters: segment starts)" if lettered else ""))
    return fig


def _fig_position_error(results, base, tx):
    fig, axs = plt.subplots(3, 1, figsize=(10, 7.5), sharex=True)
    for r in results:
        t = r.a["t"] - tx.t0
        e, s = r.a["err_ned_m"], r.a["sigma_ned_m"]
        for ax, i, sign in zip(axs, (1, 0, 2), (1, 1, -1)):
            _band(ax, t, s[:, i], r.color)
            ax.plot(t, sign * e[:, i], color=r.color, lw=0.8, label=r.name)
    tf, ef = receiver_errors(base)
    clipped = False
    for ax, i, sign, lab in zip(axs, (1, 0, 2), (1, 1, -1), ("east", "north", "up")):
        if len(tf):
            ax.plot(tf - tx.t0, sign * ef[:, i], ".", color=RECEIVER_COLOR, ms=3, label="receiver fixes")
        ax.set_ylabel(f"{lab} (m)")
        vals = np.concatenate([r.a["err_ned_m"][:, i] for r in results] + [ef[:, i]])
        lim = _clip_limit(vals, np.concatenate([3 * r.a["sigma_ned_m"][:, i] for r in results]))
        series = [(r.a["t"] - tx.t0, sign * r.a["err_ned_m"][:, i], r.color, False) for r in results]
        clipped |= _limit_and_mark(ax, -lim, lim, series + [(tf - tx.t0, sign * ef[:, i], RECEIVER_COLOR, True)])
    _mark_segments(axs, base, tx.t0)
    axs[0].legend(handles=_mode_handles(results, band=True) + (
        [Line2D([], [], marker=".", ls="", color=RECEIVER_COLOR, label="receiver fixes")] if len(tf) else []) + (
        [_beyond_handle()] if clipped else []), fontsize=8, ncol=4, loc="upper left")
    axs[0].set_title("Position error (estimate - truth) with 3-sigma bounds", pad=14)
    axs[-1].set_xlabel(tx.label)
    return fig


def _fig_attitude(results, base, tx):
    fig, axs = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    key = "err_ypr_deg" if base.has_truth else "ypr_deg"
    for r in results:
        t = r.a["t"] - tx.t0
        for ax, i, s_i, lab in zip(axs, (0, 1, 2), (2, 1, 0), ("yaw", "pitch", "roll")):
            y = r.a[key][:, i]
            ax.plot(*(_wrap_broken(t, y) if i == 0 else (t, y)), color=r.color, lw=0.8, label=r.name)
            if base.has_truth:
                _band(ax, t, r.a["sigma_ypr_deg"][:, s_i], r.color)
            ax.set_ylabel(f"{lab} error (deg)" if base.has_truth else f"{lab} (deg)")
    unknown = ~base.a["heading_known"]
    clipped = False
    if base.has_truth:
        for ax, i, s_i in zip(axs, (0, 1, 2), (2, 1, 0)):
            # The scale comes from the time the heading is known; before that the yaw error is anything.
            lim = _clip_limit(np.concatenate([r.a["err_ypr_deg"][r.a["heading_known"], i] for r in results]),
                              np.concatenate([3 * r.a["sigma_ypr_deg"][r.a["heading_known"], s_i] for r in results]))
            clipped |= _limit_and_mark(ax, -lim, lim, [(r.a["t"] - tx.t0, r.a["err_ypr_deg"][:, i], r.color, False)
                                                       for r in results])
    handles = _mode_handles(results, band=base.has_truth) + ([_beyond_handle()] if clipped else [])
    if unknown.any():
        t_known = base.a["t"][np.argmax(~unknown)] if (~unknown).any() else base.a["t"][-1]
        axs[0].axvspan(base.a["t"][0] - tx.t0, t_known - tx.t0, color="0.85", zorder=0)
        handles.append(Patch(color="0.85", label="heading not yet known"))
    _mark_segments(axs, base, tx.t0)
    axs[0].legend(handles=handles, fontsize=8, ncol=4, loc="upper left")
    axs[0].set_title("Attitude" + (" error with 3-sigma bounds" if base.has_truth else ""), pad=14)
    axs[-1].set_xlabel(tx.label)
    return fig


def _fig_sigma(results, base, tx):
    fig, axs = plt.subplots(3, 1, figsize=(10, 7.5), sharex=True)
    for r in results:
        t = r.a["t"] - tx.t0
        vel = r.a.get("sigma_v_ned_mps")
        for ax, blk in zip(axs, (r.a["sigma_ypr_deg"], vel, r.a["sigma_ned_m"])):
            if blk is None:
                continue
            for i, ls in enumerate(AXIS_STYLES):
                ax.plot(t, blk[:, i], ls, color=r.color, lw=0.9, label=f"{r.name} {'NED'[i]}")
    for ax, lab in zip(axs, ("attitude (deg)", "velocity (m/s)", "position (m)")):
        ax.set_ylabel(lab)
        ax.set_yscale("log")
    _mark_segments(axs, base, tx.t0)
    axs[0].legend(handles=_mode_handles(results) + _axis_handles(), fontsize=8, ncol=5, loc="upper right")
    axs[0].set_title("Standard deviations in NED (attitude about the N, E, D axes)", pad=14)
    axs[-1].set_xlabel(tx.label)
    return fig


def _fig_biases(results, base, tx, truth):
    fig, axs = plt.subplots(2, 3, figsize=(13, 6.5), sharex=True)
    scale = (np.degrees(1.0) * 3600.0, 1.0)
    for r in results:
        t = r.a["t"] - tx.t0
        for row, (key, k0) in enumerate((("gyro_bias", 9), ("accel_bias", 12))):
            for i in range(3):
                ax = axs[row, i]
                # A plug-in's sigma may hold only the 9 navigation states: no band for its biases.
                sigma = r.a["sigma"][:, k0 + i] if r.a["sigma"].shape[1] > k0 + i else np.full(len(t), np.nan)
                est, sig = scale[row] * r.a[key][:, i], scale[row] * sigma
                ax.fill_between(t, est - 3 * sig, est + 3 * sig, color=r.color, alpha=BAND_ALPHA, lw=0)
                ax.plot(t, est, color=r.color, lw=0.9, label=r.name)
    if truth is not None:
        tt, g, a = truth
        keep = (tt >= base.a["t"][0]) & (tt <= base.a["t"][-1])
        for row, b in enumerate((g, a)):
            for i in range(3):
                axs[row, i].plot(tt[keep] - tx.t0, scale[row] * b[keep, i], "k--", lw=0.9, label="truth")
    for i in range(3):
        axs[0, i].set_title(f"gyro {'xyz'[i]} (deg/h)")
        axs[1, i].set_title(f"accelerometer {'xyz'[i]} (m/s^2)")
    fig.supxlabel(tx.label, fontsize=10)  # once: three panels are too narrow for it each
    _mark_segments(axs.ravel(), base, tx.t0, letters=False)
    handles = _mode_handles(results, band=True)
    if truth is not None:
        handles.append(Line2D([], [], color="k", ls="--", label="truth (less the calibration)"))
    axs[0, 0].legend(handles=handles, fontsize=7, loc="best")
    fig.suptitle("Residual IMU bias estimates with 3-sigma bands (Figs 7.10-7.13)")
    return fig


def _fig_bias_sigma(results, base, tx):
    fig, axs = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    for r in results:
        if r.a["sigma"].shape[1] < 15:  # a plug-in that states no bias sigmas
            continue
        t = r.a["t"] - tx.t0
        for i, ls in enumerate(AXIS_STYLES):
            axs[0].plot(t, np.degrees(r.a["sigma"][:, 9 + i]) * 3600, ls, color=r.color, lw=0.9)
            axs[1].plot(t, r.a["sigma"][:, 12 + i], ls, color=r.color, lw=0.9)
    axs[0].set_ylabel("gyro bias sigma (deg/h)")
    axs[1].set_ylabel("accel bias sigma (m/s^2)")
    for ax in axs:
        ax.set_yscale("log")
    _mark_segments(axs, base, tx.t0)
    axs[0].legend(handles=_mode_handles(results) + _axis_handles(("x", "y", "z")), fontsize=8, ncol=5)
    axs[0].set_title("Bias standard deviations (Figs 7.23-7.26)", pad=14)
    axs[-1].set_xlabel(tx.label)
    return fig


# The fix innovations' panels: a 3D fix's innovation is in ECEF, a 2D fix's in north and east (its update
# projects the fix onto the local level).
FIX_PANELS = {KIND_FIX3: ("x", "y", "z"), KIND_FIX2: ("north", "east")}
FIX_MARKERS = {KIND_FIX3: (".", 3.0, 6.0), KIND_FIX2: ("s", 2.5, 3.0)}  # marker, size, size in the legend


def _fig_innovations(results, base, tx):
    panels = [(kind, i) for kind, axes in FIX_PANELS.items()
              if any((r.a["upd_kind"] == kind).any() for r in results) for i in range(len(axes))]
    if not panels:
        return None
    fig, axs = plt.subplots(len(panels), 1, figsize=(10, 2.5 * len(panels)), sharex=True, squeeze=False)
    for ax, (kind, i) in zip(axs[:, 0], panels):
        runs = [(r, r.a["upd_kind"] == kind) for r in results if (r.a["upd_kind"] == kind).any()]
        lim = _clip_limit(np.concatenate([r.a["upd_innovation"][k, i] for r, k in runs]),
                          np.concatenate([3 * r.a["upd_innovation_sigma"][k, i] for r, k in runs]))
        marker, ms, legend_ms = FIX_MARKERS[kind]
        clipped = False
        for r, k in runs:
            t = r.a["upd_t"][k] - tx.t0
            nu, s3 = r.a["upd_innovation"][k, i], 3 * r.a["upd_innovation_sigma"][k, i]
            inside = ~(np.abs(nu) > lim)
            ax.plot(t[inside], nu[inside], marker, color=r.color, ms=ms, ls="", label=f"{r.name} {KIND_NAMES[kind]}")
            clipped |= _mark_beyond(ax, t, nu, -lim, lim, r.color, points=True)
            _bound(ax, t, s3, r.color)
        ax.set_ylim(-lim, lim)
        ax.set_ylabel(f"{KIND_NAMES[kind]} {FIX_PANELS[kind][i]} (m)")
        if i == 0:  # each kind's first panel names its runs
            handles = [Line2D([], [], color=r.color, marker=marker, ms=legend_ms, ls="",
                              label=f"{r.name} {KIND_NAMES[kind]}")
                       for r, _ in runs] + [Line2D([], [], color="k", lw=0.6, label="+-3 sigma")]
            ax.legend(handles=handles + ([_beyond_handle()] if clipped else []), fontsize=8, ncol=3, loc="upper left")
    _mark_segments(axs[:, 0], base, tx.t0)
    axs[0, 0].set_title("Fix innovations with 3-sigma (3D fixes: ECEF x, y, z; 2D fixes: north, east); "
                        "axis clipped at high DOP", pad=14)
    axs[-1, 0].set_xlabel(tx.label)
    return fig


def _per_satellite_interval(r: Result, k: np.ndarray) -> float:
    """The median time between one satellite's updates (of the kind selected by k)."""
    t, prn = r.a["upd_t"][k], r.a["upd_id"][k]
    dt = np.concatenate([np.diff(t[prn == p]) for p in np.unique(prn)] or [np.zeros(0)])
    dt = dt[dt > 0]
    return float(np.median(dt)) if len(dt) else float("nan")


def pseudorange_nis_note(r: Result) -> tuple[str, str] | None:
    """Why a run's pseudorange NIS sits low in its 1-dof band, when it does (its median below the band's
    lower quartile): (legend text, caption text)."""
    k = r.a["upd_kind"] == KIND_PR
    nis = r.a["upd_nis"][k]
    nis = nis[np.isfinite(nis)]
    if len(nis) == 0 or np.median(nis) >= chi2.ppf(0.25, 1):
        return None
    med = float(np.median(nis))
    gm = float(r.config.get("pseudorange_error_gm_sigma_m", 0.0))
    tau = float(r.config.get("pseudorange_error_gm_tau_s", 0.0))
    dt = _per_satellite_interval(r, k)
    if gm > 0 and tau > 0 and dt > 0:
        short = f"median {med:.2g}: low by design, its sigma holds the correlated error; see the caption"
        a = np.exp(-dt / tau)
        why = (f"the preset adds each pseudorange's correlated (multipath) error, {gm:g} m at zenith with a "
               f"{tau:g} s correlation time, to every update's variance multiplied by (1 + a) / (1 - a) = "
               f"{(1 + a) / (1 - a):.0f} for one satellite's updates {dt:.2g} s apart (a = exp(-dt / tau)), so that "
               "its many correlated updates weigh as much as the independent ones they stand for. Each update's "
               "sigma is thus deliberately wide against the error the update brings afresh")
    else:
        short = f"median {med:.2g}: low by design, the preset's sigma is wide; see the caption"
        why = (f"the preset's pseudorange sigma ({float(r.config.get('pseudorange_sigma_m', 0.0)):g} m, or its "
               "elevation model) is deliberately wide against the errors of these pseudoranges")
    return short, (f"The {r.name} filter's pseudorange NIS sits low by design (median {med:.2g}, where errors as "
                   f"wide as their sigma would give {chi2.ppf(0.5, 1):.2f}): {why}.")


def _fig_satellite_innovations(results, base, tx, kind):
    """A tight filter's per-satellite updates (pseudoranges or range rates): innovations over their sigma, NIS."""
    name = KIND_NAMES[kind]
    tight = [r for r in results if (r.a["upd_kind"] == kind).any()]
    if not tight:
        return None
    fig, axs = plt.subplots(2, 1, figsize=(11, 7.5), sharex=True)
    cmap = plt.get_cmap("tab20")
    gates = [np.sqrt(np.median(r.a["upd_gate"][r.a["upd_kind"] == kind])) for r in tight]
    zlim = max(6.0, 1.3 * max(gates))
    lo, hi = chi2.ppf([0.025, 0.975], 1)
    all_nis = []
    for r, gate in zip(tight, gates):
        k = r.a["upd_kind"] == kind
        t, prn = r.a["upd_t"][k] - tx.t0, r.a["upd_id"][k]
        z = r.a["upd_innovation"][k, 0] / r.a["upd_innovation_sigma"][k, 0]
        acc = r.a["upd_accepted"][k] > 0
        for j, p in enumerate(np.unique(prn)):
            m = prn == p
            axs[0].plot(t[m & acc], z[m & acc], ".", ms=2.5, color=cmap(j % 20), label=f"PRN {int(p)}")
        if (~acc).any():  # a rejected one far out is drawn at the axis edge
            axs[0].plot(t[~acc], np.clip(z[~acc], -0.97 * zlim, 0.97 * zlim), "x", color="k", ms=4,
                        label="rejected (beyond the axis: at its edge)")
        for sgn in (1, -1):
            axs[0].axhline(sgn * 3, color="0.4", lw=0.8, ls="--")
            axs[0].axhline(sgn * gate, color="r", lw=0.8)
        nis = r.a["upd_nis"][k]
        note = pseudorange_nis_note(r) if kind == KIND_PR else None
        axs[1].semilogy(t, nis, ".", ms=2, color=r.color,
                        label=f"{r.name} {name} NIS" + (f" ({note[0]})" if note else ""))
        axs[1].axhline(gate ** 2, color="r", lw=0.8, label=f"gate {gate ** 2:.1f}")
        all_nis.append((t, nis, r.color))
    axs[1].axhspan(lo, hi, color="grey", alpha=0.2, label="95 % band, 1 dof")
    axs[0].plot([], [], color="0.4", ls="--", label="+-3")
    axs[0].plot([], [], color="r", label=f"+-gate ({gate:.2f})")
    axs[0].set_ylim(-zlim, zlim)
    axs[0].set_ylabel("innovation / sigma")
    axs[0].legend(fontsize=7, ncol=6, loc="upper left", markerscale=2)
    axs[1].set_ylabel("NIS (1 dof)")
    y_lo, y_hi = _log_limits(np.concatenate([n for _, n, _ in all_nis]), (lo, max(hi, gate ** 2)))
    if _limit_and_mark(axs[1], y_lo, y_hi, [(t, n, c, True) for t, n, c in all_nis]):
        axs[1].plot([], [], "v", color="k", label="beyond the axis (at its edge)")
    axs[1].legend(fontsize=8, loc="lower right")
    _mark_segments(axs, base, tx.t0)
    axs[0].set_title(f"Tight filter: normalised {name} innovations per satellite, and their NIS", pad=14)
    axs[-1].set_xlabel(tx.label)
    return fig


def _fig_gnss(results, base, tx):
    f = base.a["fixes"]
    fig, axs = plt.subplots(2, 1, figsize=(10, 5.5), sharex=True)
    axs[0].step(f[:, 0] - tx.t0, base.a["fix_sats"], where="post", color=RECEIVER_COLOR, label="receiver fix")
    for r in results:
        k = (r.a["upd_kind"] == KIND_PR) & (r.a["upd_accepted"] > 0)
        if k.any():
            t, n = np.unique(r.a["upd_t"][k], return_counts=True)
            axs[0].plot(t - tx.t0, n, ".", ms=3, color=r.color, label=f"{r.name} pseudoranges used")
    axs[0].set_ylabel("satellites")
    axs[0].legend(fontsize=8, loc="lower left")
    ok = f[:, 9] > 0
    axs[1].semilogy(f[ok, 0] - tx.t0, f[ok, 7], ".", ms=3, color="tab:red", label="HDOP")
    axs[1].semilogy(f[ok, 0] - tx.t0, np.where(f[ok, 9] == 2, f[ok, 8], np.nan), ".", ms=3, color="tab:purple",
                    label="VDOP (3D fixes)")
    axs[1].set_ylabel("DOP (log)")
    axs[1].legend(fontsize=8, loc="upper left")
    _mark_segments(axs, base, tx.t0)
    axs[0].set_title("GNSS: satellites used and dilution of precision", pad=14)
    axs[-1].set_xlabel(tx.label)
    return fig


def _chi2_panel(ax, series, dof: int, ylabel: str, line: bool = False) -> None:
    """A log panel of NIS or NEES values ((t, values, colour, label) each) against their 95 % chi-square
    band; its range follows the bulk of the values, the rest marked at the edge."""
    for t, v, color, label in series:
        if line:
            ax.semilogy(t, v, color=color, lw=0.6, label=label)
        else:
            ax.semilogy(t, v, ".", color=color, ms=3, label=label)
    lo, hi = chi2.ppf([0.025, 0.975], dof)
    ax.axhspan(lo, hi, color="grey", alpha=0.2, label=f"95 % band, {dof} dof")
    y_lo, y_hi = _log_limits(np.concatenate([v for _, v, _, _ in series]), (lo, hi))
    if _limit_and_mark(ax, y_lo, y_hi, [(t, v, c, not line) for t, v, c, _ in series]):
        ax.plot([], [], "v", color="k", ls="", label="beyond the axis (at its edge)")
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=8, loc="upper right")


def _fig_consistency(results, base, tx):
    """The NIS of each fix kind that has updates, and the NEES with a truth: no panel without data."""
    panels = []
    for kind, dof in ((KIND_FIX3, 3), (KIND_FIX2, 2)):
        series = [(r.a["upd_t"][k] - tx.t0, r.a["upd_nis"][k], r.color, f"{r.name} {KIND_NAMES[kind]} NIS")
                  for r in results if (k := r.a["upd_kind"] == kind).any()]
        if series:
            panels.append((series, dof, f"NIS, {KIND_NAMES[kind]}es", False, f"{KIND_NAMES[kind]} NIS ({dof} dof)"))
    if base.has_truth:
        series = [(r.a["t"] - tx.t0, r.a["nees9"], r.color, f"{r.name} NEES") for r in results]
        panels.append((series, 9, "NEES (9 nav states)", True, "NEES (9 nav states)"))
    if not panels:
        return None
    fig, axs = plt.subplots(len(panels), 1, figsize=(10, 2.6 * len(panels) + 1), sharex=True, squeeze=False)
    for ax, (series, dof, ylabel, line, _) in zip(axs[:, 0], panels):
        _chi2_panel(ax, series, dof, ylabel, line)
    _mark_segments(axs[:, 0], base, tx.t0)
    axs[0, 0].set_title("Consistency: " + ", ".join(p[4] for p in panels), pad=14)
    axs[-1, 0].set_xlabel(tx.label)
    return fig


def _fig_clock(results, base, tx, truth):
    tight = [r for r in results if "clock" in r.a]
    if not tight:
        return None
    true_clock = None
    if truth is not None and "clock_bias_s" in truth:
        weeks = int(truth["gps_week"]) - int(base.a["week"])
        tt = truth["gnss_t"] + float(truth["t0_tow_s"]) + weeks * SECONDS_PER_WEEK
        c = _core.gnss.SPEED_OF_LIGHT
        true_clock = (tt, c * truth["clock_bias_s"], c * truth["clock_drift"])
    ncol = 2 if true_clock else 1
    fig, axs = plt.subplots(2, ncol, figsize=(7 * ncol, 6), sharex=True, squeeze=False)
    clipped = np.zeros(axs.shape, bool)
    for r in tight:
        t = r.a["t"] - tx.t0
        n = r.a["sigma"].shape[1]
        settled = r.a["t"] >= r.a["t"][0] + 5.0  # the first seconds' sigmas would set the scale
        for i in (0, 1):
            est, sig = r.a["clock"][:, i], r.a["sigma"][:, n - 2 + i]
            ax = axs[i, 0]
            ax.fill_between(t, est - 3 * sig, est + 3 * sig, color=r.color, alpha=0.2, lw=0)
            ax.plot(t, est, color=r.color, lw=0.9, label=f"{r.name} estimate")
            lo, hi = np.nanmin(est[settled]), np.nanmax(est[settled])
            pad = 3 * np.nanmedian(sig[settled]) + 0.05 * (hi - lo)
            clipped[i, 0] |= _limit_and_mark(ax, lo - pad, hi + pad, [(t, est, r.color, False)])
            if true_clock:
                ref = np.interp(r.a["t"], true_clock[0], true_clock[1 + i])
                ax = axs[i, 1]
                _band(ax, t, sig, r.color, 0.2)
                ax.plot(t, est - ref, color=r.color, lw=0.9, label=f"{r.name} estimate - truth")
                lim = _clip_limit((est - ref)[settled], 3 * sig[settled])
                clipped[i, 1] |= _limit_and_mark(ax, -lim, lim, [(t, est - ref, r.color, False)])
    if true_clock:
        tt, b, d = true_clock
        keep = (tt >= base.a["t"][0]) & (tt <= base.a["t"][-1])
        axs[0, 0].plot(tt[keep] - tx.t0, b[keep], "k--", lw=0.8, label="truth")
        axs[1, 0].plot(tt[keep] - tx.t0, d[keep], "k--", lw=0.8, label="truth")
        axs[0, 1].set_ylabel("bias error (m)")
        axs[1, 1].set_ylabel("drift error (m/s)")
    axs[0, 0].set_ylabel("clock bias (m)")
    axs[1, 0].set_ylabel("clock drift (m/s)")
    for ax, cut in zip(axs.ravel(), clipped.ravel()):
        ax.legend(handles=ax.get_legend_handles_labels()[0] + _band_handles(tight, 0.2) +
                  ([_beyond_handle()] if cut else []), fontsize=8, loc="upper left")
    _mark_segments(axs.ravel(), base, tx.t0, letters=False)
    for ax in axs[-1]:
        ax.set_xlabel(tx.label)
    fig.suptitle("Receiver clock bias and drift with 3-sigma (Fig 7.27)")
    return fig


def _fig_visibility(sky: SkyData, base, tx):
    fig, ax = plt.subplots(figsize=(10, 5))
    prns = np.unique(sky.obs[:, 1]).astype(int)
    row = {p: j for j, p in enumerate(prns)}
    sc = ax.scatter(sky.obs[:, 0] - tx.t0, [row[int(p)] for p in sky.obs[:, 1]], c=sky.obs[:, 2], s=3,
                    cmap="viridis", marker="s", label="tracked (colour: C/N0)")
    fig.colorbar(sc, ax=ax, label="C/N0 (dB-Hz)")
    ax.set_yticks(range(len(prns)), [f"PRN {p}" for p in prns])
    ax.set_xlabel(tx.label)
    _mark_segments([ax], base, tx.t0)
    ax.legend(fontsize=8, loc="lower left")
    ax.set_title("Satellites tracked by the receiver (Fig 6.3)", pad=14)
    return fig


def _fig_skyplot(sky: SkyData):
    if not sky.tracks:
        return None
    fig = plt.figure(figsize=(6.5, 6.5))
    ax = fig.add_subplot(projection="polar")
    ax.set_theta_zero_location("N")
    ax.set_theta_direction(-1)
    cmap = plt.get_cmap("tab20")
    for j, (prn, (_, az, el)) in enumerate(sorted(sky.tracks.items())):
        up = el > 0
        ax.plot(az[up], 90 - np.degrees(el[up]), "-", color=cmap(j % 20), lw=2, label=f"PRN {prn}")
        if up.any():
            k = np.flatnonzero(up)[-1]
            ax.text(az[k], 90 - np.degrees(el[k]), str(prn), fontsize=8)
    ax.set_rlim(0, 90)
    ax.set_rticks([0, 30, 60, 90], labels=["90", "60", "30", "0"])
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    ax.set_title("Sky plot of the tracked satellites (elevation, deg; Fig 6.4)")
    return fig


def _has_drift(r: Result) -> bool:
    return len(r.a.get("drift_t_s", ())) > 0 and bool(r.run.get("scoring"))


def _outage_spans(r: Result) -> np.ndarray:
    """The outages shaded in the drift figure, [start, end) in the results' time: the schedule, or for an
    ins run its free navigation from the scoring's start to the end."""
    if r.run.get("mode") == "ins" and r.run["scoring"].get("ins_free_from") is not None:
        return np.array([[r.run["scoring"]["ins_free_from"], r.a["t"][-1]]])
    return np.asarray(r.a.get("outages", np.zeros((0, 2))), float).reshape(-1, 2)


def _fig_outage_drift(results, tx):
    """Drift vs time in outage (one line per outage and run), and the error against the reference over time
    with the outages shaded."""
    scored = [r for r in results if _has_drift(r)]
    if not scored:
        return None
    fig, (ax, bx) = plt.subplots(2, 1, figsize=(10, 7))
    for r in scored:
        k = r.a["drift_outage"]
        for j in np.unique(k):
            m = k == j
            ax.plot(r.a["drift_t_s"][m], r.a["drift_h_m"][m], "-", color=r.color, lw=1.0)
            ax.plot(r.a["drift_t_s"][m], r.a["drift_v_m"][m], ":", color=r.color, lw=1.0)
        e = r.a["ref_err_ned_m"]
        bx.plot(*_gapped(r.a["ref_t"] - tx.t0, np.hypot(e[:, 0], e[:, 1])), "-", color=r.color, lw=0.8)
    for a, b in _outage_spans(scored[0]):
        bx.axvspan(a - tx.t0, b - tx.t0, color="0.85", zorder=0)
    ax.set_xlabel("time since the outage began (s)")
    ax.set_ylabel("drift (m)")
    ax.legend(handles=_mode_handles(scored) + [Line2D([], [], color="k", ls="-", label="horizontal"),
                                               Line2D([], [], color="k", ls=":", label="vertical")],
              fontsize=8, loc="upper left")
    ref = scored[0].run["scoring"]
    ax.set_title(f"Drift vs time in outage, against {Path(ref['reference']).name} at the {ref['point']} point")
    bx.set_yscale("log")
    bx.set_xlabel(tx.label)
    bx.set_ylabel("horizontal error (m)")
    bx.legend(handles=_mode_handles(scored) + [Patch(color="0.85", label="outage")], fontsize=8, loc="upper left")
    bx.set_title("Horizontal error against the reference")
    return fig


def _time_axis(base: Result) -> TimeAxis:
    return TimeAxis(time_origin(base), f"time ({time_origin_text(base)})")


def build_figures(results: list[Result]) -> dict:
    """Every figure of the report, by file name, from loaded results (``report.build_figures`` loads them);
    the caller saves or inspects and closes them."""
    base = results[0]
    tx = _time_axis(base)
    truth = _truth_file(base) if base.has_truth else None  # replay --no-truth: none in the figures either
    figs = {"trajectory.png": _fig_trajectory(results, base, tx)}
    if base.has_truth:
        figs["position_error.png"] = _fig_position_error(results, base, tx)
    figs["attitude.png"] = _fig_attitude(results, base, tx)
    figs["sigma.png"] = _fig_sigma(results, base, tx)
    figs["biases.png"] = _fig_biases(results, base, tx, true_residual_biases(base, truth))
    figs["bias_sigma.png"] = _fig_bias_sigma(results, base, tx)
    figs["innovations.png"] = _fig_innovations(results, base, tx)
    figs["pseudorange.png"] = _fig_satellite_innovations(results, base, tx, KIND_PR)
    figs["range_rate.png"] = _fig_satellite_innovations(results, base, tx, KIND_RR)
    figs["gnss.png"] = _fig_gnss(results, base, tx)
    figs["consistency.png"] = _fig_consistency(results, base, tx)
    figs["clock.png"] = _fig_clock(results, base, tx, truth)
    figs["outage_drift.png"] = _fig_outage_drift(results, tx)
    sky = sky_data(base)
    if sky is not None and len(sky.obs):
        figs["visibility.png"] = _fig_visibility(sky, base, tx)
        figs["skyplot.png"] = _fig_skyplot(sky)
    return {k: v for k, v in figs.items() if v is not None}


def figures(results: list[Result], out: Path) -> list[str]:
    """Write every figure as PNG into `out`; returns the file names."""
    names = []
    for name, fig in build_figures(results).items():
        fig.tight_layout()
        fig.savefig(out / name, dpi=110)
        plt.close(fig)
        names.append(name)
    return names


# ---------------------------------------------------------------- captions

EDGE_NOTE = "A triangle at an axis edge stands for values beyond it (the axis follows the bulk of the data)."
CAPTIONS = {
    "trajectory.png": "Horizontal track, metres east and north of the first epoch: each filter's solution, the "
                      "receiver's own fixes (circles) and, with a truth, the true track (dashed). Where the filter "
                      "leaves the fixes or the truth, it has lost its way.",
    "position_error.png": "Position error (estimate minus truth) east, north and up, each filter in its colour with "
                          "its +-3-sigma band shaded in the same colour, and the receiver's own fixes' errors as "
                          "green dots. A consistent filter keeps its error inside its band almost all the time; an "
                          "error that leaves the band is one the filter does not know about. " + EDGE_NOTE,
    "attitude.png": "Attitude error (estimate minus truth) in yaw, pitch and roll with the +-3-sigma band in the "
                    "filter's colour; grey shading: before the heading is known (the yaw error means nothing there). "
                    "Yaw's line is broken where it wraps at +-180 deg. " + EDGE_NOTE,
    "sigma.png": "The filter's standard deviations (log scale) of attitude about the north, east and down axes, of "
                 "velocity and of position; line style: axis. They shrink as updates come and grow without them; "
                 "yaw (down) shrinks only once the motion makes it observable.",
    "biases.png": "Residual gyro and accelerometer bias estimates with their +-3-sigma bands in the filter's colour; "
                  "with a simulated truth, the true residual (truth less the calibration) dashed. The truth should "
                  "stay inside the band; a band that stays wide means the motion did not make that bias observable.",
    "bias_sigma.png": "The bias estimates' standard deviations (log scale); line style: axis. Where one falls, the "
                      "motion (turns, accelerations) made that bias observable.",
    "innovations.png": "Fix innovations (fix minus the filter's prediction) with the innovation's +-3 sigma: 3D "
                       "fixes in ECEF x, y and z, 2D fixes in north and east (the local level their update uses). "
                       "Almost all should lie inside their lines; a run outside is a fix error or a filter that is "
                       "too sure (Table 7.4 lists them). " + EDGE_NOTE,
    "pseudorange.png": "Top: each satellite's pseudorange innovation over its sigma (colour: PRN), with +-3 and the "
                       "gate (rejected updates as crosses). Bottom: their NIS against the 95 % band of chi-square "
                       "with 1 dof; mostly below the band: the update's sigma is wider than its error, above: "
                       "narrower. " + EDGE_NOTE,
    "range_rate.png": "Top: each satellite's range-rate (Doppler) innovation over its sigma (colour: PRN), with +-3 "
                      "and the gate (rejected updates as crosses). Bottom: their NIS against the 95 % band of "
                      "chi-square with 1 dof; mostly below the band: the sigma is wider than the error, above: "
                      "narrower. " + EDGE_NOTE,
    "gnss.png": "Satellites in the receiver's fix (line) and pseudoranges the tight filter used (dots) per epoch, and "
                "the fixes' HDOP and VDOP (log scale). Few satellites and a high DOP explain large fix errors.",
    "consistency.png": "Consistency: the NIS of the fix updates, each kind against the 95 % chi-square band of its "
                       "own dof (3D fixes 3, 2D fixes 2), and with a truth the NEES of the 9 navigation states "
                       "against the 9-dof band. Mostly below a band: the filter is more cautious than its errors "
                       "need; above: over-confident. " + EDGE_NOTE,
    "clock.png": "The tight filter's receiver clock bias and drift (in metres and m/s) with +-3-sigma bands in the "
                 "filter's colour; with a simulated truth, the truth (dashed) and the estimate's error beside it, "
                 "which should stay inside its band. " + EDGE_NOTE,
    "outage_drift.png": "Top: drift from the reference since each outage began (solid: horizontal, dotted: "
                        "vertical; one line per outage and filter). Bottom: horizontal error against the reference "
                        "over time with the outages shaded: the same outages and times as the drift table.",
    "visibility.png": "Satellites the receiver tracked over time, coloured by C/N0; a gap is a lost satellite.",
    "skyplot.png": "Sky tracks of the tracked satellites: azimuth clockwise from north, elevation from the horizon "
                   "(outer circle) to the zenith (centre); the number marks a track's end.",
}
ATTITUDE_WITHOUT_TRUTH = ("Yaw, pitch and roll as each filter estimates them (no truth to compare with); grey "
                          "shading: before the heading is known. Yaw's line is broken where it wraps at +-180 deg.")
TIMELESS = ("trajectory.png", "skyplot.png")


def figure_captions(results: list[Result]) -> dict[str, str]:
    """What each figure shows and how to read it, by file name, with this report's time origin and the
    reasons for what looks wrong by design (the tight filter's low pseudorange NIS)."""
    base = results[0]
    origin = f"Time axes: {time_origin_text(base)}, as in the tables."
    caps = dict(CAPTIONS, **({} if base.has_truth else {"attitude.png": ATTITUDE_WITHOUT_TRUTH}))
    caps = {name: text if name in TIMELESS else f"{text} {origin}" for name, text in caps.items()}
    if "seg_t" in base.a and base.has_truth:
        caps["trajectory.png"] += " Letters: where the truth's segments start."
    notes = [n[1] for r in results if (n := pseudorange_nis_note(r))]
    if notes:
        caps["pseudorange.png"] += " " + " ".join(notes)
    return caps
