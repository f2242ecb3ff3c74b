"""The report's figures of the GNSS side: innovations (per fix, per satellite), the receiver's
fixes, its clock, satellite visibility and the sky plot.
"""

from __future__ import annotations


import numpy as np

from .. import _core
from .data import KIND_FIX2, KIND_FIX3, KIND_NAMES, KIND_PR, RECEIVER_COLOR, Result, SkyData
from ..formats.gpstime import SECONDS_PER_WEEK
from .draw import (Line2D, sigma_band, band_handles, beyond_handle, bound, clip_limit, limit_and_mark, log_limits,
                   mark_beyond, mark_segments, chi2, plt)


# The fix innovations' panels: a 3D fix's innovation is in ECEF, a 2D fix's in north and east (its update
# projects the fix onto the local level).
FIX_PANELS = {KIND_FIX3: ("x", "y", "z"), KIND_FIX2: ("north", "east")}
FIX_MARKERS = {KIND_FIX3: (".", 3.0, 6.0), KIND_FIX2: ("s", 2.5, 3.0)}  # marker, size, size in the legend


def fig_innovations(results, base, tx):
    panels = [(kind, i) for kind, axes in FIX_PANELS.items()
              if any((r.a["upd_kind"] == kind).any() for r in results) for i in range(len(axes))]
    if not panels:
        return None
    fig, axs = plt.subplots(len(panels), 1, figsize=(10, 2.5 * len(panels)), sharex=True, squeeze=False)
    for ax, (kind, i) in zip(axs[:, 0], panels):
        runs = [(r, r.a["upd_kind"] == kind) for r in results if (r.a["upd_kind"] == kind).any()]
        lim = clip_limit(np.concatenate([r.a["upd_innovation"][k, i] for r, k in runs]),
                          np.concatenate([3 * r.a["upd_innovation_sigma"][k, i] for r, k in runs]))
        marker, ms, legend_ms = FIX_MARKERS[kind]
        clipped = False
        for r, k in runs:
            t = r.a["upd_t"][k] - tx.t0
            nu, s3 = r.a["upd_innovation"][k, i], 3 * r.a["upd_innovation_sigma"][k, i]
            inside = ~(np.abs(nu) > lim)
            ax.plot(t[inside], nu[inside], marker, color=r.color, ms=ms, ls="", label=f"{r.name} {KIND_NAMES[kind]}")
            clipped |= mark_beyond(ax, t, nu, -lim, lim, r.color, points=True)
            bound(ax, t, s3, r.color)
        ax.set_ylim(-lim, lim)
        ax.set_ylabel(f"{KIND_NAMES[kind]} {FIX_PANELS[kind][i]} (m)")
        if i == 0:  # each kind's first panel names its runs
            handles = [Line2D([], [], color=r.color, marker=marker, ms=legend_ms, ls="",
                              label=f"{r.name} {KIND_NAMES[kind]}")
                       for r, _ in runs] + [Line2D([], [], color="k", lw=0.6, label="+-3 sigma")]
            ax.legend(handles=handles + ([beyond_handle()] if clipped else []), fontsize=8, ncol=3, loc="upper left")
    mark_segments(axs[:, 0], base, tx.t0)
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


def fig_satellite_innovations(results, base, tx, kind):
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
    y_lo, y_hi = log_limits(np.concatenate([n for _, n, _ in all_nis]), (lo, max(hi, gate ** 2)))
    if limit_and_mark(axs[1], y_lo, y_hi, [(t, n, c, True) for t, n, c in all_nis]):
        axs[1].plot([], [], "v", color="k", label="beyond the axis (at its edge)")
    axs[1].legend(fontsize=8, loc="lower right")
    mark_segments(axs, base, tx.t0)
    axs[0].set_title(f"Tight filter: normalised {name} innovations per satellite, and their NIS", pad=14)
    axs[-1].set_xlabel(tx.label)
    return fig


def fig_gnss(results, base, tx):
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
    mark_segments(axs, base, tx.t0)
    axs[0].set_title("GNSS: satellites used and dilution of precision", pad=14)
    axs[-1].set_xlabel(tx.label)
    return fig


def fig_clock(results, base, tx, truth):
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
            clipped[i, 0] |= limit_and_mark(ax, lo - pad, hi + pad, [(t, est, r.color, False)])
            if true_clock:
                ref = np.interp(r.a["t"], true_clock[0], true_clock[1 + i])
                ax = axs[i, 1]
                sigma_band(ax, t, sig, r.color, 0.2)
                ax.plot(t, est - ref, color=r.color, lw=0.9, label=f"{r.name} estimate - truth")
                lim = clip_limit((est - ref)[settled], 3 * sig[settled])
                clipped[i, 1] |= limit_and_mark(ax, -lim, lim, [(t, est - ref, r.color, False)])
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
        ax.legend(handles=ax.get_legend_handles_labels()[0] + band_handles(tight, 0.2) +
                  ([beyond_handle()] if cut else []), fontsize=8, loc="upper left")
    mark_segments(axs.ravel(), base, tx.t0, letters=False)
    for ax in axs[-1]:
        ax.set_xlabel(tx.label)
    fig.suptitle("Receiver clock bias and drift with 3-sigma (Fig 7.27)")
    return fig


def fig_visibility(sky: SkyData, base, tx):
    fig, ax = plt.subplots(figsize=(10, 5))
    prns = np.unique(sky.obs[:, 1]).astype(int)
    row = {p: j for j, p in enumerate(prns)}
    sc = ax.scatter(sky.obs[:, 0] - tx.t0, [row[int(p)] for p in sky.obs[:, 1]], c=sky.obs[:, 2], s=3,
                    cmap="viridis", marker="s", label="tracked (colour: C/N0)")
    fig.colorbar(sc, ax=ax, label="C/N0 (dB-Hz)")
    ax.set_yticks(range(len(prns)), [f"PRN {p}" for p in prns])
    ax.set_xlabel(tx.label)
    mark_segments([ax], base, tx.t0)
    ax.legend(fontsize=8, loc="lower left")
    ax.set_title("Satellites tracked by the receiver (Fig 6.3)", pad=14)
    return fig


def fig_skyplot(sky: SkyData):
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
