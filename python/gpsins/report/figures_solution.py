"""The report's figures of the solution: trajectory, position and attitude errors, sigmas, biases,
consistency (NEES, NIS) and the drift through outages.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import _core, evaluate
from .data import AXIS_STYLES, KIND_FIX2, KIND_FIX3, KIND_NAMES, RECEIVER_COLOR, Result, receiver_errors, truth_ecef
from .draw import (BAND_ALPHA, Line2D, Patch, axis_handles, sigma_band, beyond_handle, clip_limit, gapped,
                   limit_and_mark, log_limits, mark_segments, mode_handles, wrap_broken, chi2, plt)


def fig_trajectory(results, base, tx):
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


def fig_position_error(results, base, tx):
    fig, axs = plt.subplots(3, 1, figsize=(10, 7.5), sharex=True)
    for r in results:
        t = r.a["t"] - tx.t0
        e, s = r.a["err_ned_m"], r.a["sigma_ned_m"]
        for ax, i, sign in zip(axs, (1, 0, 2), (1, 1, -1)):
            sigma_band(ax, t, s[:, i], r.color)
            ax.plot(t, sign * e[:, i], color=r.color, lw=0.8, label=r.name)
    tf, ef = receiver_errors(base)
    clipped = False
    for ax, i, sign, lab in zip(axs, (1, 0, 2), (1, 1, -1), ("east", "north", "up")):
        if len(tf):
            ax.plot(tf - tx.t0, sign * ef[:, i], ".", color=RECEIVER_COLOR, ms=3, label="receiver fixes")
        ax.set_ylabel(f"{lab} (m)")
        vals = np.concatenate([r.a["err_ned_m"][:, i] for r in results] + [ef[:, i]])
        lim = clip_limit(vals, np.concatenate([3 * r.a["sigma_ned_m"][:, i] for r in results]))
        series = [(r.a["t"] - tx.t0, sign * r.a["err_ned_m"][:, i], r.color, False) for r in results]
        clipped |= limit_and_mark(ax, -lim, lim, series + [(tf - tx.t0, sign * ef[:, i], RECEIVER_COLOR, True)])
    mark_segments(axs, base, tx.t0)
    axs[0].legend(handles=mode_handles(results, band=True) + (
        [Line2D([], [], marker=".", ls="", color=RECEIVER_COLOR, label="receiver fixes")] if len(tf) else []) + (
        [beyond_handle()] if clipped else []), fontsize=8, ncol=4, loc="upper left")
    axs[0].set_title("Position error (estimate - truth) with 3-sigma bounds", pad=14)
    axs[-1].set_xlabel(tx.label)
    return fig


def fig_attitude(results, base, tx):
    fig, axs = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    key = "err_ypr_deg" if base.has_truth else "ypr_deg"
    for r in results:
        t = r.a["t"] - tx.t0
        for ax, i, s_i, lab in zip(axs, (0, 1, 2), (2, 1, 0), ("yaw", "pitch", "roll")):
            y = r.a[key][:, i]
            ax.plot(*(wrap_broken(t, y) if i == 0 else (t, y)), color=r.color, lw=0.8, label=r.name)
            if base.has_truth:
                sigma_band(ax, t, r.a["sigma_ypr_deg"][:, s_i], r.color)
            ax.set_ylabel(f"{lab} error (deg)" if base.has_truth else f"{lab} (deg)")
    unknown = ~base.a["heading_known"]
    clipped = False
    if base.has_truth:
        for ax, i, s_i in zip(axs, (0, 1, 2), (2, 1, 0)):
            # The scale comes from the time the heading is known; before that the yaw error is anything.
            lim = clip_limit(np.concatenate([r.a["err_ypr_deg"][r.a["heading_known"], i] for r in results]),
                              np.concatenate([3 * r.a["sigma_ypr_deg"][r.a["heading_known"], s_i] for r in results]))
            clipped |= limit_and_mark(ax, -lim, lim, [(r.a["t"] - tx.t0, r.a["err_ypr_deg"][:, i], r.color, False)
                                                       for r in results])
    handles = mode_handles(results, band=base.has_truth) + ([beyond_handle()] if clipped else [])
    if unknown.any():
        t_known = base.a["t"][np.argmax(~unknown)] if (~unknown).any() else base.a["t"][-1]
        axs[0].axvspan(base.a["t"][0] - tx.t0, t_known - tx.t0, color="0.85", zorder=0)
        handles.append(Patch(color="0.85", label="heading not yet known"))
    mark_segments(axs, base, tx.t0)
    axs[0].legend(handles=handles, fontsize=8, ncol=4, loc="upper left")
    axs[0].set_title("Attitude" + (" error with 3-sigma bounds" if base.has_truth else ""), pad=14)
    axs[-1].set_xlabel(tx.label)
    return fig


def fig_sigma(results, base, tx):
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
    mark_segments(axs, base, tx.t0)
    axs[0].legend(handles=mode_handles(results) + axis_handles(), fontsize=8, ncol=5, loc="upper right")
    axs[0].set_title("Standard deviations in NED (attitude about the N, E, D axes)", pad=14)
    axs[-1].set_xlabel(tx.label)
    return fig


def fig_biases(results, base, tx, truth):
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
    mark_segments(axs.ravel(), base, tx.t0, letters=False)
    handles = mode_handles(results, band=True)
    if truth is not None:
        handles.append(Line2D([], [], color="k", ls="--", label="truth (less the calibration)"))
    axs[0, 0].legend(handles=handles, fontsize=7, loc="best")
    fig.suptitle("Residual IMU bias estimates with 3-sigma bands (Figs 7.10-7.13)")
    return fig


def fig_bias_sigma(results, base, tx):
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
    mark_segments(axs, base, tx.t0)
    axs[0].legend(handles=mode_handles(results) + axis_handles(("x", "y", "z")), fontsize=8, ncol=5)
    axs[0].set_title("Bias standard deviations (Figs 7.23-7.26)", pad=14)
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
    y_lo, y_hi = log_limits(np.concatenate([v for _, v, _, _ in series]), (lo, hi))
    if limit_and_mark(ax, y_lo, y_hi, [(t, v, c, not line) for t, v, c, _ in series]):
        ax.plot([], [], "v", color="k", ls="", label="beyond the axis (at its edge)")
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=8, loc="upper right")


def fig_consistency(results, base, tx):
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
    mark_segments(axs[:, 0], base, tx.t0)
    axs[0, 0].set_title("Consistency: " + ", ".join(p[4] for p in panels), pad=14)
    axs[-1, 0].set_xlabel(tx.label)
    return fig


def _has_drift(r: Result) -> bool:
    return len(r.a.get("drift_t_s", ())) > 0 and bool(r.run.get("scoring"))


def _outage_spans(r: Result) -> np.ndarray:
    """The outages shaded in the drift figure, [start, end) in the results' time: the schedule, or for an
    ins run its free navigation from the scoring's start to the end."""
    if r.run.get("mode") == "ins" and r.run["scoring"].get("ins_free_from") is not None:
        return np.array([[r.run["scoring"]["ins_free_from"], r.a["t"][-1]]])
    return np.asarray(r.a.get("outages", np.zeros((0, 2))), float).reshape(-1, 2)


def fig_outage_drift(results, tx):
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
        bx.plot(*gapped(r.a["ref_t"] - tx.t0, np.hypot(e[:, 0], e[:, 1])), "-", color=r.color, lw=0.8)
    for a, b in _outage_spans(scored[0]):
        bx.axvspan(a - tx.t0, b - tx.t0, color="0.85", zorder=0)
    ax.set_xlabel("time since the outage began (s)")
    ax.set_ylabel("drift (m)")
    ax.legend(handles=mode_handles(scored) + [Line2D([], [], color="k", ls="-", label="horizontal"),
                                               Line2D([], [], color="k", ls=":", label="vertical")],
              fontsize=8, loc="upper left")
    ref = scored[0].run["scoring"]
    ax.set_title(f"Drift vs time in outage, against {Path(ref['reference']).name} at the {ref['point']} point")
    bx.set_yscale("log")
    bx.set_xlabel(tx.label)
    bx.set_ylabel("horizontal error (m)")
    bx.legend(handles=mode_handles(scored) + [Patch(color="0.85", label="outage")], fontsize=8, loc="upper left")
    bx.set_title("Horizontal error against the reference")
    return fig
