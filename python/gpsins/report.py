"""The evaluation report: the report's chapter 7 figures, a Markdown page and
the same page as one self-contained HTML file (figures embedded), from one or
more replay results directories (one per filter mode), side by side.

Figures are built by ``build_figures`` (matplotlib Figure objects, so tests can
inspect what each panel holds) and written by ``figures``. Everything comes
from the results tables (``results.load``; a long run's epochs decimated) and ``run.json``; the truth's biases and clock and the
satellites' visibility and sky tracks come from the session's files
(``truth.npz`` and the receiver's ID 23 and ID 22) when they are still there.
"""

from __future__ import annotations

import base64
import html
import io
import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import _core, evaluate, lazy, noise_from_data, results

# Loaded on first use: replay imports this module for its outage table and draws nothing.
plt = lazy.module("matplotlib.pyplot", before=lazy.agg_backend)
Line2D = lazy.name("matplotlib.lines", "Line2D", before=lazy.agg_backend)
Patch = lazy.name("matplotlib.patches", "Patch", before=lazy.agg_backend)
chi2 = lazy.name("scipy.stats", "chi2")

KIND_FIX3, KIND_FIX2, KIND_PR, KIND_RR = 1, 2, 6, 9
KIND_FIX = (KIND_FIX3, KIND_FIX2)
KIND_NAMES = {KIND_FIX3: "3D fix", KIND_FIX2: "2D fix", KIND_PR: "pseudorange", KIND_RR: "range rate"}
PER_SATELLITE = (KIND_PR, KIND_RR)
MODE_COLORS = {"loose": "tab:blue", "tight": "tab:orange", "ins": "tab:red"}
OTHER_COLORS = ("tab:purple", "tab:brown", "tab:pink")
RECEIVER_COLOR = "tab:green"
AXIS_STYLES = ("-", "--", ":")
SECONDS_PER_WEEK = 604800.0


@dataclass
class Result:
    name: str
    path: Path
    a: dict
    run: dict
    color: str = "tab:blue"
    config: dict = field(default_factory=dict)

    @property
    def has_truth(self) -> bool:
        return "err_ned_m" in self.a

    @property
    def session(self) -> Path | None:
        """The replayed session directory: as recorded in run.json, else beside the results directory."""
        if not self.run.get("session"):
            return None
        p = Path(self.run["session"])
        for cand in (p, self.path.parent / p.name, self.path.parent.parent / p.name):
            if cand.is_dir():
                return cand
        return None


MAX_PLOT_EPOCHS = 100_000  # a longer run's epochs are decimated for the figures (its numbers come from run.json)


def load(path: str | Path, max_epochs: int = MAX_PLOT_EPOCHS) -> Result:
    path = Path(path)
    stride = max(1, -(-results.epochs(path) // max_epochs))
    a = results.load(path, stride=stride)
    run = json.loads((path / "run.json").read_text(encoding="utf-8"))
    cfg_path = path / "config.toml"
    cfg = tomllib.loads(cfg_path.read_text(encoding="utf-8")) if cfg_path.exists() else {}
    name = run.get("mode", path.name)
    if run.get("stretch"):
        name += f" stretch {run['stretch']['index']}"
    return Result(name, path, a, run, MODE_COLORS.get(name, "tab:blue"), cfg)


def result_dirs(path: str | Path) -> list[Path]:
    """The replay results in a directory ``gpsins replay --out`` wrote: itself, or its runs per mode
    (``--mode both``) and per stretch (a restarted receiver), in order."""
    path = Path(path)
    if (path / "run.json").is_file():
        return [path]
    parts = sorted((p for p in path.glob("stretch-*") if p.name[len("stretch-"):].isdigit()),
                   key=lambda p: int(p.name[len("stretch-"):]))
    found = [r for part in parts or [path] for r in (part, *(part / m for m in MODE_COLORS))
             if (r / "run.json").is_file()]
    return found or [path]


def smoothed_companion(r: Result) -> Result | None:
    """A replay run with ``--smooth`` as a second run: the smoothed arrays (``smooth_*``) in place of the
    forward ones, its errors and scoring from run.json's "smoothed", so every figure and table shows
    forward and smoothed side by side."""
    keys = [k for k in r.a if k.startswith("smooth_")]
    if not keys or r.name.endswith(" smoothed"):
        return None
    a = {k: v for k, v in r.a.items() if not k.startswith("smooth_")}
    a.update({k[len("smooth_"):]: r.a[k] for k in keys})
    sm = r.run.get("smoothed") or {}
    run = dict(r.run, errors=sm.get("errors", {}), mode=f"{r.name} smoothed")
    if sm.get("scoring"):
        run["scoring"] = {**(r.run.get("scoring") or {}), **sm["scoring"]}
    return Result(f"{r.name} smoothed", r.path, a, run, "tab:cyan", r.config)


def _load_all(paths) -> list[Result]:
    results = [p if isinstance(p, Result) else load(p) for p in paths]
    names = {r.name for r in results}
    results = [x for r in results for x in (r, None if f"{r.name} smoothed" in names else smoothed_companion(r))
               if x is not None]
    used = set()
    for r in results:  # two runs of the same mode get different colours
        if r.color in used:
            r.color = next(c for c in OTHER_COLORS if c not in used)
        used.add(r.color)
    return results


# ---------------------------------------------------------------- numbers


def truth_ecef(r: Result) -> np.ndarray:
    """The truth's position at the solution epochs: estimate minus its NED error."""
    llh = r.a["llh"]
    c = evaluate.c_en(llh[:, 0], llh[:, 1])
    return r.a["r_ecef"] - np.einsum("nij,nj->ni", c, r.a["err_ned_m"])


def receiver_errors(r: Result) -> tuple[np.ndarray, np.ndarray]:
    """Times and NED errors (fix - truth) of the receiver's own fixes inside the truth's span."""
    if not r.has_truth:
        return np.zeros(0), np.zeros((0, 3))
    f = r.a["fixes"]
    f = f[f[:, 9] > 0]
    ok = np.isfinite(r.a["err_ned_m"][:, 0])
    t, tr = r.a["t"][ok], truth_ecef(r)[ok]
    f = f[(f[:, 0] >= t[0]) & (f[:, 0] <= t[-1])]
    ref = np.column_stack([np.interp(f[:, 0], t, tr[:, i]) for i in range(3)])
    llh = _core.ecef_to_geodetic(ref)
    c = evaluate.c_en(llh[:, 0], llh[:, 1])
    return f[:, 0], np.einsum("nji,nj->ni", c, f[:, 1:4] - ref)


def _stats(e: np.ndarray) -> dict:
    if len(e) == 0:
        return {}
    h = np.hypot(e[:, 0], e[:, 1])
    return {"h_rms": float(np.sqrt(np.mean(h ** 2))), "h_max": float(h.max()),
            "v_rms": float(np.sqrt(np.mean(e[:, 2] ** 2))), "v_max": float(np.abs(e[:, 2]).max())}


def segment_table(r: Result) -> list[dict]:
    """RMS and maximum horizontal and vertical error per truth segment (Table 6.1 style)."""
    if not r.has_truth or "seg_t" not in r.a:
        return []
    t, e, hk = r.a["t"], r.a["err_ned_m"], r.a["heading_known"]
    f, sats = r.a["fixes"], r.a["fix_sats"]
    rows = []
    for label, (t0, t1) in zip(r.a["seg_labels"], r.a["seg_t"]):
        m = (t >= t0) & (t < t1) & hk & np.isfinite(e[:, 0])
        fm = (f[:, 0] >= t0) & (f[:, 0] < t1)
        row = {"segment": str(label), "sats_min": int(sats[fm].min()) if fm.any() else 0,
               "sats_max": int(sats[fm].max()) if fm.any() else 0, "t0": float(t0), "t1": float(t1)}
        row.update(_stats(e[m]))
        if "nees9" in r.a:  # the segment's mean 9-state NEES (a lap's consistency)
            n9 = r.a["nees9"][m]
            n9 = n9[np.isfinite(n9)]
            row["nees9_mean"] = float(n9.mean()) if len(n9) else None
        rows.append(row)
    return rows


def receiver_segment_table(r: Result) -> list[dict]:
    """The same per segment for the receiver's own fixes."""
    if not r.has_truth or "seg_t" not in r.a:
        return []
    t, e = receiver_errors(r)
    return [{"segment": str(label), **_stats(e[(t >= t0) & (t < t1)])}
            for label, (t0, t1) in zip(r.a["seg_labels"], r.a["seg_t"])]


def innovation_intervals(r: Result, k: float = 3.0) -> list[dict]:
    """Table 7.4: stretches of consecutive updates (per kind, per satellite) with an innovation beyond k sigma."""
    a = r.a
    rows = []
    for kind in (KIND_FIX3, KIND_FIX2, KIND_PR, KIND_RR):
        sel = a["upd_kind"] == kind
        ids = np.unique(a["upd_id"][sel]) if kind in PER_SATELLITE else [None]
        for sid in ids:
            m = sel if sid is None else sel & (a["upd_id"] == sid)
            idx = np.flatnonzero(m)
            if len(idx) == 0:
                continue
            nu, s = a["upd_innovation"][idx], a["upd_innovation_sigma"][idx]
            with np.errstate(invalid="ignore", divide="ignore"):
                ratio = np.nanmax(np.where(np.isfinite(nu), np.abs(nu) / s, 0.0), axis=1)
            out = ratio > k
            edges = np.flatnonzero(np.diff(np.concatenate([[0], out.astype(int), [0]])))
            for i0, i1 in zip(edges[::2], edges[1::2]):
                rows.append({"mode": r.name, "kind": KIND_NAMES[kind], "prn": None if sid is None else int(sid),
                             "t_start": float(a["upd_t"][idx[i0]]), "t_end": float(a["upd_t"][idx[i1 - 1]]),
                             "updates": int(i1 - i0), "max_ratio": float(ratio[i0:i1].max()),
                             "rejected": int(np.sum(a["upd_accepted"][idx[i0:i1]] == 0))})
    return sorted(rows, key=lambda x: x["t_start"])


def _truth_file(r: Result) -> dict | None:
    s = r.session
    if s is None:
        return None
    for p in (s / "truth.npz", s.parent / "truth.npz"):
        if p.exists():
            z = np.load(p)
            return {k: z[k] for k in z.files}
    return None


def true_residual_biases(r: Result, z: dict | None) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The simulator's gyro and accelerometer biases less the configuration's calibration, on the result's times."""
    if z is None or "gyro_bias" not in z:
        return None
    t = z["tow_s"] + (int(z["gps_week"]) - int(r.a["week"])) * SECONDS_PER_WEEK
    cal_g = np.broadcast_to(np.asarray(r.config.get("gyro_bias_cal_rad_per_s", 0.0), float), (3,))
    cal_a = np.broadcast_to(np.asarray(r.config.get("accel_bias_cal_mps2", 0.0), float), (3,))
    return t, z["gyro_bias"] - cal_g, z["accel_bias"] - cal_a


@dataclass
class SkyData:
    """What the receiver tracked: (t, prn, C/N0) per observation; az/el tracks per satellite."""

    obs: np.ndarray
    tracks: dict


def sky_data(r: Result, step_s: float = 10.0) -> SkyData | None:
    """Visibility and sky tracks from the session's ID 23 and ID 22 (None without the session)."""
    s = r.session
    if s is None:
        return None
    from collections import Counter

    from . import logs, measurements

    try:
        session = logs.read_session(s)
        gps = measurements.decode_gps(session.sensors["gps"], Counter())
    except (ValueError, OSError, KeyError):
        return None
    obs = gps.pseudorange_table()[:, [0, 1, 3]]
    ephs = {}
    for e in gps.decoded_ephemerides(Counter()):
        ephs.setdefault(int(e.prn), e)
    rx = r.a["r_ecef"][0]
    tracks = {}
    for prn in np.unique(obs[:, 1]).astype(int):
        if prn not in ephs:
            continue
        t = obs[obs[:, 1] == prn, 0]
        ts = np.arange(t[0], t[-1] + step_s / 2, step_s)
        ae = np.array([_core.gnss.az_el(rx, _core.gnss.sat_state(ephs[prn], gps.week * SECONDS_PER_WEEK + x)[0])
                       for x in ts]).reshape(-1, 2)
        tracks[prn] = (ts, ae[:, 0], ae[:, 1])
    return SkyData(obs, tracks)


# ---------------------------------------------------------------- figures


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


def _mode_handles(results, band: bool = False) -> list:
    h = [Line2D([], [], color=r.color, lw=1.2, label=r.name) for r in results]
    if band:
        h.append(Patch(color="0.5", alpha=0.25, label="3-sigma band (mode's colour)"))
    return h


def _axis_handles(names=("north", "east", "down")) -> list:
    return [Line2D([], [], color="k", ls=ls, lw=1, label=n) for ls, n in zip(AXIS_STYLES, names)]


def _band(ax, t, s, color, alpha=0.15):
    ax.fill_between(t, -3 * s, 3 * s, color=color, alpha=alpha, lw=0)


def _gapped(t: np.ndarray, y: np.ndarray, gap_s: float = 2.5) -> tuple[np.ndarray, np.ndarray]:
    """Break a line where the samples are further apart than gap_s (no bridges across outages)."""
    cut = np.flatnonzero(np.diff(t) > gap_s) + 1
    return np.insert(t.astype(float), cut, np.nan), np.insert(y.astype(float), cut, np.nan)


def _clip_limit(values: np.ndarray, bounds: np.ndarray) -> float:
    """A symmetric y limit showing the usual values and bounds; outliers are drawn at the edge."""
    v, b = np.abs(values[np.isfinite(values)]), np.abs(bounds[np.isfinite(bounds)])
    if len(v) == 0 and len(b) == 0:
        return 1.0
    lim = max(np.percentile(v, 99) if len(v) else 0.0, 2.0 * np.median(b) if len(b) else 0.0)
    return 1.2 * lim if lim > 0 else 1.0


def _fig_trajectory(results, base, t0):
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
    if base.has_truth:
        true_ne = (truth_ecef(base) - o) @ c
        ax.plot(true_ne[:, 1], true_ne[:, 0], "k--", lw=0.8, label="truth")
        if "seg_t" in base.a:
            for label, (s0, _) in zip(base.a["seg_labels"], base.a["seg_t"]):
                k = np.searchsorted(base.a["t"], s0)
                if k < len(true_ne) and np.isfinite(true_ne[k, 0]):
                    ax.annotate(str(label).split("-")[0], true_ne[k, [1, 0]], fontsize=8, color="k")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_aspect("equal", "datalim")
    ax.legend(loc="best", fontsize=8)
    ax.set_title("Trajectory (letters: segment starts)")
    return fig


def _fig_position_error(results, base, t0):
    fig, axs = plt.subplots(3, 1, figsize=(10, 7.5), sharex=True)
    for r in results:
        t = r.a["t"] - t0
        e, s = r.a["err_ned_m"], r.a["sigma_ned_m"]
        for ax, i, sign in zip(axs, (1, 0, 2), (1, 1, -1)):
            _band(ax, t, s[:, i], r.color)
            ax.plot(t, sign * e[:, i], color=r.color, lw=0.8, label=r.name)
    tf, ef = receiver_errors(base)
    lims = []
    for ax, i, sign, lab in zip(axs, (1, 0, 2), (1, 1, -1), ("east", "north", "up")):
        if len(tf):
            ax.plot(tf - t0, sign * ef[:, i], ".", color=RECEIVER_COLOR, ms=3, label="receiver fixes")
        ax.set_ylabel(f"{lab} (m)")
        vals = np.concatenate([r.a["err_ned_m"][:, i] for r in results] + [ef[:, i]])
        lims.append(_clip_limit(vals, np.concatenate([3 * r.a["sigma_ned_m"][:, i] for r in results])))
        ax.set_ylim(-lims[-1], lims[-1])
    _mark_segments(axs, base, t0)
    axs[0].legend(handles=_mode_handles(results, band=True) + (
        [Line2D([], [], marker=".", ls="", color=RECEIVER_COLOR, label="receiver fixes")] if len(tf) else []),
        fontsize=8, ncol=4, loc="upper left")
    axs[0].set_title("Position error (estimate - truth) with 3-sigma bounds", pad=14)
    axs[-1].set_xlabel("time (s)")
    return fig


def _fig_attitude(results, base, t0):
    fig, axs = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    for r in results:
        t = r.a["t"] - t0
        for ax, i, s_i, lab in zip(axs, (0, 1, 2), (2, 1, 0), ("yaw", "pitch", "roll")):
            if r.has_truth:
                ax.plot(t, r.a["err_ypr_deg"][:, i], color=r.color, lw=0.8, label=r.name)
                _band(ax, t, r.a["sigma_ypr_deg"][:, s_i], r.color)
                ax.set_ylabel(f"{lab} error (deg)")
            else:
                ax.plot(t, r.a["ypr_deg"][:, i], color=r.color, lw=0.8, label=r.name)
                ax.set_ylabel(f"{lab} (deg)")
    unknown = ~base.a["heading_known"]
    if base.has_truth:
        for ax, i, s_i in zip(axs, (0, 1, 2), (2, 1, 0)):
            # The scale comes from the time the heading is known; before that the yaw error is anything.
            lim = _clip_limit(np.concatenate([r.a["err_ypr_deg"][r.a["heading_known"], i] for r in results]),
                              np.concatenate([3 * r.a["sigma_ypr_deg"][r.a["heading_known"], s_i] for r in results]))
            ax.set_ylim(-lim, lim)
    handles = _mode_handles(results, band=base.has_truth)
    if unknown.any():
        t_known = base.a["t"][np.argmax(~unknown)] - t0 if (~unknown).any() else base.a["t"][-1] - t0
        axs[0].axvspan(0.0, t_known, color="0.85", zorder=0)
        handles.append(Patch(color="0.85", label="heading not yet known"))
    _mark_segments(axs, base, t0)
    axs[0].legend(handles=handles, fontsize=8, ncol=4, loc="upper left")
    axs[0].set_title("Attitude" + (" error with 3-sigma bounds" if base.has_truth else ""), pad=14)
    axs[-1].set_xlabel("time (s)")
    return fig


def _fig_sigma(results, base, t0):
    fig, axs = plt.subplots(3, 1, figsize=(10, 7.5), sharex=True)
    for r in results:
        t = r.a["t"] - t0
        vel = r.a.get("sigma_v_ned_mps")
        for ax, blk in zip(axs, (r.a["sigma_ypr_deg"], vel, r.a["sigma_ned_m"])):
            if blk is None:
                continue
            for i, ls in enumerate(AXIS_STYLES):
                ax.plot(t, blk[:, i], ls, color=r.color, lw=0.9, label=f"{r.name} {'NED'[i]}")
    for ax, lab in zip(axs, ("attitude (deg)", "velocity (m/s)", "position (m)")):
        ax.set_ylabel(lab)
        ax.set_yscale("log")
    _mark_segments(axs, base, t0)
    axs[0].legend(handles=_mode_handles(results) + _axis_handles(), fontsize=8, ncol=5, loc="upper right")
    axs[0].set_title("Standard deviations in NED (attitude about the N, E, D axes)", pad=14)
    axs[-1].set_xlabel("time (s)")
    return fig


def _fig_biases(results, base, t0, truth):
    fig, axs = plt.subplots(2, 3, figsize=(13, 6.5), sharex=True)
    scale = (np.degrees(1.0) * 3600.0, 1.0)
    for r in results:
        t = r.a["t"] - t0
        for row, (key, k0) in enumerate((("gyro_bias", 9), ("accel_bias", 12))):
            for i in range(3):
                ax = axs[row, i]
                est, sig = scale[row] * r.a[key][:, i], scale[row] * r.a["sigma"][:, k0 + i]
                ax.fill_between(t, est - 3 * sig, est + 3 * sig, color=r.color, alpha=0.15, lw=0)
                ax.plot(t, est, color=r.color, lw=0.9, label=r.name)
    if truth is not None:
        tt, g, a = truth
        keep = (tt >= base.a["t"][0]) & (tt <= base.a["t"][-1])
        for row, b in enumerate((g, a)):
            for i in range(3):
                axs[row, i].plot(tt[keep] - t0, scale[row] * b[keep, i], "k--", lw=0.9, label="truth")
    for i in range(3):
        axs[0, i].set_title(f"gyro {'xyz'[i]} (deg/h)")
        axs[1, i].set_title(f"accelerometer {'xyz'[i]} (m/s^2)")
        axs[1, i].set_xlabel("time (s)")
    _mark_segments(axs.ravel(), base, t0, letters=False)
    handles = _mode_handles(results, band=True)
    if truth is not None:
        handles.append(Line2D([], [], color="k", ls="--", label="truth (less the calibration)"))
    axs[0, 0].legend(handles=handles, fontsize=7, loc="best")
    fig.suptitle("Residual IMU bias estimates with 3-sigma bands (Figs 7.10-7.13)")
    return fig


def _fig_bias_sigma(results, base, t0):
    fig, axs = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    for r in results:
        t = r.a["t"] - t0
        for i, ls in enumerate(AXIS_STYLES):
            axs[0].plot(t, np.degrees(r.a["sigma"][:, 9 + i]) * 3600, ls, color=r.color, lw=0.9)
            axs[1].plot(t, r.a["sigma"][:, 12 + i], ls, color=r.color, lw=0.9)
    axs[0].set_ylabel("gyro bias sigma (deg/h)")
    axs[1].set_ylabel("accel bias sigma (m/s^2)")
    for ax in axs:
        ax.set_yscale("log")
    _mark_segments(axs, base, t0)
    axs[0].legend(handles=_mode_handles(results) + _axis_handles(("x", "y", "z")), fontsize=8, ncol=5)
    axs[0].set_title("Bias standard deviations (Figs 7.23-7.26)", pad=14)
    axs[-1].set_xlabel("time (s)")
    return fig


def _fig_innovations(results, base, t0):
    with_fixes = [r for r in results if np.isin(r.a["upd_kind"], KIND_FIX).any()]
    fig, axs = plt.subplots(3, 1, figsize=(10, 7.5), sharex=True)
    clipped_any = False
    for i, ax in enumerate(axs):
        vals, bounds = [], []
        for r in with_fixes:
            k = np.isin(r.a["upd_kind"], KIND_FIX)
            vals.append(r.a["upd_innovation"][k, i])
            bounds.append(3 * r.a["upd_innovation_sigma"][k, i])
        lim = _clip_limit(np.concatenate(vals or [np.zeros(0)]), np.concatenate(bounds or [np.zeros(0)]))
        for r in with_fixes:
            for kind, marker in ((KIND_FIX3, "."), (KIND_FIX2, "s")):
                k = r.a["upd_kind"] == kind
                if not k.any():
                    continue
                t = r.a["upd_t"][k] - t0
                nu, s3 = r.a["upd_innovation"][k, i], 3 * r.a["upd_innovation_sigma"][k, i]
                out = np.abs(nu) > lim
                clipped_any |= bool(out.any())
                ax.plot(t[~out], nu[~out], marker, color=r.color, ms=3 if marker == "." else 2.5, ls="",
                        label=f"{r.name} {KIND_NAMES[kind]}")
                for sgn, mk in ((1, "^"), (-1, "v")):
                    o = out & (np.sign(nu) == sgn)
                    ax.plot(t[o], np.full(o.sum(), sgn * 0.97 * lim), mk, color=r.color, ms=4, ls="")
                ax.plot(*_gapped(t, s3), "-", color=r.color, lw=0.6)
                ax.plot(*_gapped(t, -s3), "-", color=r.color, lw=0.6)
        ax.set_ylim(-lim, lim)
        ax.set_ylabel(f"{'xyz'[i]} (m)" if i < 2 else "z (m)")
    _mark_segments(axs, base, t0)
    handles = [Line2D([], [], color=r.color, marker=".", ls="", label=f"{r.name} 3D fix") for r in with_fixes]
    handles += [Line2D([], [], color=r.color, marker="s", ms=3, ls="", label=f"{r.name} 2D fix (N, E)")
                for r in with_fixes if (r.a["upd_kind"] == KIND_FIX2).any()]
    handles.append(Line2D([], [], color="k", lw=0.6, label="+-3 sigma"))
    if clipped_any:
        handles.append(Line2D([], [], color="k", marker="^", ls="", label="beyond the axis"))
    axs[0].legend(handles=handles, fontsize=8, ncol=3, loc="upper left")
    axs[0].set_title("Fix innovations (ECEF x, y, z; 2D fixes: north, east) with 3-sigma; axis clipped at high DOP",
                     pad=14)
    axs[-1].set_xlabel("time (s)")
    return fig


def _fig_satellite_innovations(results, base, t0, kind):
    """A tight filter's per-satellite updates (pseudoranges or range rates): innovations over their sigma, NIS."""
    name = KIND_NAMES[kind]
    tight = [r for r in results if (r.a["upd_kind"] == kind).any()]
    if not tight:
        return None
    fig, axs = plt.subplots(2, 1, figsize=(11, 7.5), sharex=True)
    cmap = plt.get_cmap("tab20")
    for r in tight:
        k = r.a["upd_kind"] == kind
        t, prn = r.a["upd_t"][k] - t0, r.a["upd_id"][k]
        z = r.a["upd_innovation"][k, 0] / r.a["upd_innovation_sigma"][k, 0]
        acc = r.a["upd_accepted"][k] > 0
        for j, p in enumerate(np.unique(prn)):
            m = prn == p
            axs[0].plot(t[m & acc], z[m & acc], ".", ms=2.5, color=cmap(j % 20), label=f"PRN {int(p)}")
        if (~acc).any():
            axs[0].plot(t[~acc], np.clip(z[~acc], -12, 12), "x", color="k", ms=4, label="rejected (clipped at 12)")
        gate = np.sqrt(np.median(r.a["upd_gate"][k]))
        for sgn in (1, -1):
            axs[0].axhline(sgn * 3, color="0.4", lw=0.8, ls="--")
            axs[0].axhline(sgn * gate, color="r", lw=0.8)
        nis = r.a["upd_nis"][k]
        axs[1].semilogy(t, nis, ".", ms=2, color=r.color, label=f"{r.name} {name} NIS")
        axs[1].axhline(gate ** 2, color="r", lw=0.8, label=f"gate {gate ** 2:.1f}")
    lo, hi = chi2.ppf([0.025, 0.975], 1)
    axs[1].axhspan(lo, hi, color="grey", alpha=0.2, label="95 % band, 1 dof")
    axs[0].plot([], [], color="0.4", ls="--", label="+-3")
    axs[0].plot([], [], color="r", label=f"+-gate ({gate:.2f})")
    axs[0].set_ylim(-max(6.0, 1.3 * gate), max(6.0, 1.3 * gate))
    axs[0].set_ylabel("innovation / sigma")
    axs[0].legend(fontsize=7, ncol=6, loc="upper left", markerscale=2)
    axs[1].set_ylabel("NIS (1 dof)")
    axs[1].set_ylim(1e-5, max(100.0, gate ** 2 * 3))
    axs[1].legend(fontsize=8, loc="lower right")
    _mark_segments(axs, base, t0)
    axs[0].set_title(f"Tight filter: normalised {name} innovations per satellite, and their NIS", pad=14)
    axs[-1].set_xlabel("time (s)")
    return fig


def _fig_gnss(results, base, t0):
    f = base.a["fixes"]
    fig, axs = plt.subplots(2, 1, figsize=(10, 5.5), sharex=True)
    axs[0].step(f[:, 0] - t0, base.a["fix_sats"], where="post", color=RECEIVER_COLOR, label="receiver fix")
    for r in results:
        k = (r.a["upd_kind"] == KIND_PR) & (r.a["upd_accepted"] > 0)
        if k.any():
            t, n = np.unique(r.a["upd_t"][k], return_counts=True)
            axs[0].plot(t - t0, n, ".", ms=3, color=r.color, label=f"{r.name} pseudoranges used")
    axs[0].set_ylabel("satellites")
    axs[0].legend(fontsize=8, loc="lower left")
    ok = f[:, 9] > 0
    axs[1].semilogy(f[ok, 0] - t0, f[ok, 7], ".", ms=3, color="tab:red", label="HDOP")
    axs[1].semilogy(f[ok, 0] - t0, np.where(f[ok, 9] == 2, f[ok, 8], np.nan), ".", ms=3, color="tab:purple",
                    label="VDOP (3D fixes)")
    axs[1].set_ylabel("DOP (log)")
    axs[1].legend(fontsize=8, loc="upper left")
    _mark_segments(axs, base, t0)
    axs[0].set_title("GNSS: satellites used and dilution of precision", pad=14)
    axs[-1].set_xlabel("time (s)")
    return fig


def _fig_consistency(results, base, t0):
    n = 3 if base.has_truth else 2
    fig, axs = plt.subplots(n, 1, figsize=(10, 2.6 * n + 1), sharex=True)
    for ax, kind, dof in ((axs[0], KIND_FIX3, 3), (axs[1], KIND_FIX2, 2)):
        drawn = False
        for r in results:
            k = r.a["upd_kind"] == kind
            if k.any():
                ax.semilogy(r.a["upd_t"][k] - t0, r.a["upd_nis"][k], ".", color=r.color, ms=3,
                            label=f"{r.name} {KIND_NAMES[kind]} NIS")
                drawn = True
        lo, hi = chi2.ppf([0.025, 0.975], dof)
        ax.axhspan(lo, hi, color="grey", alpha=0.2, label=f"95 % band, {dof} dof")
        ax.set_ylabel(f"NIS, {KIND_NAMES[kind]}s")
        if not drawn:
            ax.text(0.5, 0.5, f"no {KIND_NAMES[kind]} updates", transform=ax.transAxes, ha="center", color="0.4")
        ax.legend(fontsize=8, loc="upper right")
    if base.has_truth:
        for r in results:
            axs[2].semilogy(r.a["t"] - t0, r.a["nees9"], color=r.color, lw=0.6, label=f"{r.name} NEES")
        lo, hi = chi2.ppf([0.025, 0.975], 9)
        axs[2].axhspan(lo, hi, color="grey", alpha=0.2, label="95 % band, 9 dof")
        axs[2].set_ylabel("NEES (9 nav states)")
        axs[2].legend(fontsize=8, loc="upper right")
    _mark_segments(axs, base, t0)
    axs[0].set_title("Consistency: NIS of the fixes (3D and 2D each against its own dof) and NEES", pad=14)
    axs[-1].set_xlabel("time (s)")
    return fig


def _fig_clock(results, base, t0, truth):
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
    for r in tight:
        t = r.a["t"] - t0
        n = r.a["sigma"].shape[1]
        settled = r.a["t"] >= r.a["t"][0] + 5.0  # the first seconds' sigmas would set the scale
        for i in (0, 1):
            est, sig = r.a["clock"][:, i], r.a["sigma"][:, n - 2 + i]
            ax = axs[i, 0]
            ax.fill_between(t, est - 3 * sig, est + 3 * sig, color=r.color, alpha=0.2, lw=0)
            ax.plot(t, est, color=r.color, lw=0.9, label=f"{r.name} estimate")
            lo, hi = np.nanmin(est[settled]), np.nanmax(est[settled])
            pad = 3 * np.nanmedian(sig[settled]) + 0.05 * (hi - lo)
            ax.set_ylim(lo - pad, hi + pad)
            if true_clock:
                ref = np.interp(r.a["t"], true_clock[0], true_clock[1 + i])
                ax = axs[i, 1]
                _band(ax, t, sig, r.color, 0.2)
                ax.plot(t, est - ref, color=r.color, lw=0.9, label=f"{r.name} estimate - truth")
                lim = _clip_limit((est - ref)[settled], 3 * sig[settled])
                ax.set_ylim(-lim, lim)
    if true_clock:
        tt, b, d = true_clock
        keep = (tt >= base.a["t"][0]) & (tt <= base.a["t"][-1])
        axs[0, 0].plot(tt[keep] - t0, b[keep], "k--", lw=0.8, label="truth")
        axs[1, 0].plot(tt[keep] - t0, d[keep], "k--", lw=0.8, label="truth")
        axs[0, 1].set_ylabel("bias error (m)")
        axs[1, 1].set_ylabel("drift error (m/s)")
    axs[0, 0].set_ylabel("clock bias (m)")
    axs[1, 0].set_ylabel("clock drift (m/s)")
    for ax in axs.ravel():
        ax.plot([], [], color="0.5", alpha=0.4, lw=6, label="3-sigma band")
        ax.legend(fontsize=8, loc="upper left")
    _mark_segments(axs.ravel(), base, t0, letters=False)
    for ax in axs[-1]:
        ax.set_xlabel("time (s)")
    fig.suptitle("Receiver clock bias and drift with 3-sigma (Fig 7.27)")
    return fig


def _fig_visibility(sky: SkyData, base, t0):
    fig, ax = plt.subplots(figsize=(10, 5))
    prns = np.unique(sky.obs[:, 1]).astype(int)
    row = {p: j for j, p in enumerate(prns)}
    sc = ax.scatter(sky.obs[:, 0] - t0, [row[int(p)] for p in sky.obs[:, 1]], c=sky.obs[:, 2], s=3, cmap="viridis",
                    marker="s", label="tracked (colour: C/N0)")
    fig.colorbar(sc, ax=ax, label="C/N0 (dB-Hz)")
    ax.set_yticks(range(len(prns)), [f"PRN {p}" for p in prns])
    ax.set_xlabel("time (s)")
    _mark_segments([ax], base, t0)
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


def shows_outage_table(run: dict) -> bool:
    """Worth a table of its own: outages were scored, or the reference is a file (not the session's truth,
    whose errors the truth tables already give)."""
    sc = run.get("scoring") or {}
    return bool(sc) and (sc.get("n_outages", 0) > 0 or sc.get("point") == "antenna")


def _fig_outage_drift(results, t0):
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
        bx.plot(*_gapped(r.a["ref_t"] - t0, np.hypot(e[:, 0], e[:, 1])), "-", color=r.color, lw=0.8)
    sched = scored[0].a["outages"] if "outages" in scored[0].a else np.zeros((0, 2))
    if scored[0].run.get("mode") == "ins" and scored[0].run["scoring"].get("ins_free_from") is not None:
        sched = np.array([[scored[0].run["scoring"]["ins_free_from"], scored[0].a["t"][-1]]])
    for a, b in np.asarray(sched).reshape(-1, 2):
        bx.axvspan(a - t0, b - t0, color="0.85", zorder=0)
    ax.set_xlabel("time since the outage began (s)")
    ax.set_ylabel("drift (m)")
    ax.legend(handles=_mode_handles(scored) + [Line2D([], [], color="k", ls="-", label="horizontal"),
                                               Line2D([], [], color="k", ls=":", label="vertical")],
              fontsize=8, loc="upper left")
    ref = scored[0].run["scoring"]
    ax.set_title(f"Drift vs time in outage, against {Path(ref['reference']).name} at the {ref['point']} point")
    bx.set_yscale("log")
    bx.set_xlabel("time (s)")
    bx.set_ylabel("horizontal error (m)")
    bx.legend(handles=_mode_handles(scored) + [Patch(color="0.85", label="outage")], fontsize=8, loc="upper left")
    bx.set_title("Horizontal error against the reference")
    return fig


def build_figures(results: list[Result]) -> dict[str, plt.Figure]:
    """Every figure of the report, by file name; the caller saves or inspects and closes them."""
    results = _load_all(results)
    base = results[0]
    t0 = base.a["t"][0]
    truth = _truth_file(base) if base.has_truth else None  # replay --no-truth: none in the figures either
    figs = {"trajectory.png": _fig_trajectory(results, base, t0)}
    if base.has_truth:
        figs["position_error.png"] = _fig_position_error(results, base, t0)
    figs["attitude.png"] = _fig_attitude(results, base, t0)
    figs["sigma.png"] = _fig_sigma(results, base, t0)
    figs["biases.png"] = _fig_biases(results, base, t0, true_residual_biases(base, truth))
    figs["bias_sigma.png"] = _fig_bias_sigma(results, base, t0)
    figs["innovations.png"] = _fig_innovations(results, base, t0)
    figs["pseudorange.png"] = _fig_satellite_innovations(results, base, t0, KIND_PR)
    figs["range_rate.png"] = _fig_satellite_innovations(results, base, t0, KIND_RR)
    figs["gnss.png"] = _fig_gnss(results, base, t0)
    figs["consistency.png"] = _fig_consistency(results, base, t0)
    figs["clock.png"] = _fig_clock(results, base, t0, truth)
    figs["outage_drift.png"] = _fig_outage_drift(results, t0)
    sky = sky_data(base)
    if sky is not None and len(sky.obs):
        figs["visibility.png"] = _fig_visibility(sky, base, t0)
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


# ---------------------------------------------------------------- pages


def _fmt(x, d=2):
    return "-" if x is None else f"{x:.{d}f}"


def page_tables(results: list[Result]) -> list[tuple[str, list[str], list[list[str]]]]:
    """The page's tables as (title, header, rows) of text, shared by the Markdown and HTML pages."""
    tables = []
    segs = [(r.name, segment_table(r)) for r in results]
    rec = receiver_segment_table(results[0])
    if any(t for _, t in segs):
        head = ["segment", "sats"] + [f"{n} {c} rms / max (m)" for n, _ in segs for c in ("H", "V")]
        if rec:
            head += ["receiver H rms / max (m)", "receiver V rms / max (m)"]
        head += [f"{n} NEES" for n, _ in segs]
        rows = []
        for i, row in enumerate(segs[0][1]):
            cells = [row["segment"], f"{row['sats_min']}-{row['sats_max']}"]
            for _, tab in segs + ([("receiver", rec)] if rec else []):
                rr = tab[i]
                cells += [f"{_fmt(rr.get('h_rms'))} / {_fmt(rr.get('h_max'))}",
                          f"{_fmt(rr.get('v_rms'))} / {_fmt(rr.get('v_max'))}"]
            cells += [_fmt(tab[i].get("nees9_mean")) for _, tab in segs]
            rows.append(cells)
        tables.append(("Errors per segment (Table 6.1)", head, rows))
    t0 = results[0].a["t"][0]
    iv = [x for r in results for x in innovation_intervals(r)]
    head = ["mode", "update", "PRN", "from (s)", "to (s)", "updates", "max |innovation| / sigma", "rejected"]
    rows = [[x["mode"], x["kind"], "-" if x["prn"] is None else str(x["prn"]), f"{x['t_start'] - t0:.1f}",
             f"{x['t_end'] - t0:.1f}", str(x["updates"]), f"{x['max_ratio']:.1f}", str(x["rejected"])] for x in iv]
    tables.append(("Intervals with innovations outside 3 sigma (Table 7.4)", head, rows))
    groups: dict = {}  # runs with the same outages share a table (an ins run's free stretch is its own)
    for r in results:
        if shows_outage_table(r.run):
            key = tuple((o["start"], o["end"]) for o in r.run["scoring"]["per_outage"])
            groups.setdefault(key, []).append(r)
    tables += [outage_page_table(g, t0) for g in groups.values()]
    return tables


def outage_page_table(scored: list[Result], t0: float):
    """Per outage the maximum horizontal and vertical drift of each run (runs with the same outages), then
    mean, worst and RMS of the per-outage maxima and the RMS outside outages: (title, header, rows)."""
    t0 = scored[0].run.get("outages", {}).get("gnss_first_t", t0)  # times from the first GNSS epoch, as --outages
    head = ["outage", "from (s)", "to (s)", "ref epochs"] + [f"{r.name} {c} (m)" for r in scored for c in ("H", "V")]
    rows = []
    first = scored[0].run["scoring"]["per_outage"]
    for j, o in enumerate(first):
        cells = [str(j + 1), f"{o['start'] - t0:.1f}", f"{o['end'] - t0:.1f}", str(o["n_ref"])]
        for r in scored:
            po = r.run["scoring"]["per_outage"]
            oo = po[j] if j < len(po) else {}
            cells += [_fmt(oo.get("max_h_m")), _fmt(oo.get("max_v_m"))]
        rows.append(cells)
    for stat in ("mean", "worst", "rms"):
        rows.append([stat, "", "", ""] + [_fmt(r.run["scoring"][f"{c}_m"][stat])
                                          for r in scored for c in ("horizontal", "vertical")])
    rows.append(["outside RMS", "", "", str(scored[0].run["scoring"]["outside"]["n"])] +
                [_fmt(r.run["scoring"]["outside"][f"rms_{c}_m"], 3) for r in scored for c in ("h", "v")])
    ref = scored[0].run["scoring"]
    what = "free navigation (--mode ins)" if "ins_free_from" in ref else "per outage"
    return (f"Drift {what} against {Path(ref['reference']).name} ({ref['point']} point)", head, rows)


def _run_lines(r: Result) -> list[str]:
    run = r.run
    al = run.get("alignment") or {}
    lines = [f"{run.get('kind', 'session')}: {Path(run['session']).name}; IMU samples {run['imu_samples']}; "
             f"filter wall time {run['wall_time_s']['filter_s']:.2f} s (replay {run['wall_time_s']['total_s']:.2f} s)"]
    if al:
        lines.append(f"alignment: {al['method']}, IMU clock {al['imu_clock_ppm']:+.1f} ppm, "
                     f"{al['imu_frames_missing']} frames missing, clock steps {al['clock_steps_s']}")
    p = run.get("provenance")
    if p:
        sim = p.get("simulation") or {}
        lines.append(f"made by gpsins {p['gpsins']}" + (f": `{p['command']}`" if p.get("command") else "") +
                     f"; configuration sha256 {p['config_sha256'][:16]}" +
                     (f"; scenario {sim['scenario']}, seed {sim['seed']}" if sim.get("scenario") else ""))
    lines += ["counters: " + ", ".join(f"{k} {v}" for k, v in run["counters"].items() if v),
              "skipped: " + (", ".join(f"{k}: {v}" for k, v in run["skipped"].items()) or "nothing")]
    e = run.get("errors") or {}
    if e:
        inside = e.get("inside_3_sigma")
        lines.append(f"errors vs truth: horizontal RMS {_fmt(e.get('horizontal_rms_m'))} m "
                     f"(max {_fmt(e.get('horizontal_max_m'))}), vertical RMS {_fmt(e.get('vertical_rms_m'))} m "
                     f"(max {_fmt(e.get('vertical_max_m'))}), mean NEES {_fmt(e.get('nees9_mean'))} (9 dof), "
                     f"inside 3 sigma {_fmt(None if inside is None else 100 * inside, 1)} %")
    sc = run.get("scoring") or {}
    if shows_outage_table(run):
        lines.append(f"against {Path(sc['reference']).name} ({sc['point']} point): RMS of the per-outage maximum "
                     f"horizontal drift {sc['horizontal_m']['rms']:.2f} m over {sc['n_scored']} outages; outside "
                     f"outages RMS {sc['outside']['rms_h_m']:.3f} m horizontal, {sc['outside']['rms_v_m']:.3f} m "
                     "vertical")
    return lines


def _warning_lines(results: list[Result]) -> list[str]:
    """What went wrong in any run (replay's health lines: divergence, resets, sources often refused)."""
    return [f"{r.name}: {w}" for r in results for w in r.run.get("health", [])]


def _receiver_line(r: Result) -> str | None:
    _, e = receiver_errors(r)
    s = _stats(e)
    if not s:
        return None
    return (f"receiver's own fixes vs truth: horizontal RMS {s['h_rms']:.2f} m (max {s['h_max']:.2f}), "
            f"vertical RMS {s['v_rms']:.2f} m (max {s['v_max']:.2f}) over {len(e)} fixes")


def summary_markdown(results: list[Result], figs: list[str]) -> str:
    results = _load_all(results)
    lines = ["# gpsins replay report", ""]
    lines += [f"**WARNING: {w}**" for w in _warning_lines(results)] + ([""] if _warning_lines(results) else [])
    for r in results:
        lines += [f"## {r.name}", ""] + [f"- {x}" for x in _run_lines(r) + noise_from_data.summary_lines(r.run)] + [""]
    rec = _receiver_line(results[0])
    if rec:
        lines += [f"- {rec}", ""]
    for title, head, rows in page_tables(results):
        lines += [f"## {title}", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        lines += ["| " + " | ".join(c) + " |" for c in rows] or ["| none |" + " |" * (len(head) - 1)]
        lines.append("")
    lines += ["## Figures", ""] + [f"![{f}]({f})" for f in figs] + [""]
    return "\n".join(lines)


def summary_html(results: list[Result], figs: list[str], fig_dir: Path) -> str:
    """One self-contained page: the same text and tables, every figure embedded as base64 PNG."""
    results = _load_all(results)
    esc = html.escape
    parts = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8"><title>gpsins replay report</title>',
             "<style>body{font-family:sans-serif;max-width:1200px;margin:auto;padding:1em}"
             "table{border-collapse:collapse;font-size:90%}td,th{border:1px solid #bbb;padding:2px 6px;"
             "text-align:right}td:first-child{text-align:left}img{max-width:100%}</style></head><body>",
             "<h1>gpsins replay report</h1>"]
    parts += [f'<p style="color:#b00"><b>WARNING: {esc(w)}</b></p>' for w in _warning_lines(results)]
    for r in results:
        parts.append(f"<h2>{esc(r.name)}</h2><ul>"
                     + "".join(f"<li>{esc(x)}</li>" for x in _run_lines(r) + noise_from_data.summary_lines(r.run)) + "</ul>")
    rec = _receiver_line(results[0])
    if rec:
        parts.append(f"<ul><li>{esc(rec)}</li></ul>")
    for title, head, rows in page_tables(results):
        parts.append(f"<h2>{esc(title)}</h2><table><tr>" + "".join(f"<th>{esc(h)}</th>" for h in head) + "</tr>")
        parts += ["<tr>" + "".join(f"<td>{esc(c)}</td>" for c in row) + "</tr>" for row in rows]
        parts.append("</table>" + ("" if rows else "<p>none</p>"))
    parts.append("<h2>Figures</h2>")
    for f in figs:
        data = base64.b64encode((fig_dir / f).read_bytes()).decode("ascii")
        parts.append(f'<figure><img alt="{esc(f)}" src="data:image/png;base64,{data}"><figcaption>{esc(f)}'
                     "</figcaption></figure>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def make_report(paths: list[str | Path], out: str | Path) -> Path:
    """Figures, report.md and the self-contained report.html in `out`; returns the Markdown page."""
    results = _load_all(paths)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    figs = figures(results, out)
    page = out / "report.md"
    page.write_text(summary_markdown(results, figs), encoding="utf-8")
    (out / "report.html").write_text(summary_html(results, figs, out), encoding="utf-8")
    return page


# ---------------------------------------------------------------- terminal


def comparison_tables(results: list[Result]) -> list:
    """Rich tables for the terminal: the totals, then the errors per segment (Table 6.1 style)."""
    from rich.table import Table

    totals = Table(title="Errors vs truth", title_justify="left")
    totals.add_column("")
    for r in results:
        totals.add_column(r.name, justify="right")
    _, rec_e = receiver_errors(results[0])
    rec = _stats(rec_e)
    if rec:
        totals.add_column("receiver", justify="right")
    for key, lab, rkey in (("horizontal_rms_m", "H RMS (m)", "h_rms"), ("horizontal_max_m", "H max (m)", "h_max"),
                           ("vertical_rms_m", "V RMS (m)", "v_rms"), ("vertical_max_m", "V max (m)", "v_max"),
                           ("nees9_mean", "mean NEES", None), ("inside_3_sigma", "inside 3 sigma (%)", None)):
        scale = 100.0 if key == "inside_3_sigma" else 1.0
        cells = [_fmt(None if (v := (r.run.get("errors") or {}).get(key)) is None else scale * v) for r in results]
        if rec:
            cells.append(_fmt(rec.get(rkey)) if rkey else "")
        totals.add_row(lab, *cells)
    tables = [totals] if any(r.run.get("errors") for r in results) else []
    segs = [segment_table(r) for r in results]
    if any(segs):
        per = Table(title="Errors per segment (Table 6.1): RMS (max), m", title_justify="left")
        per.add_column("segment")
        per.add_column("sats", justify="right")
        rec_rows = receiver_segment_table(results[0])
        names = [r.name for r in results] + (["receiver"] if rec_rows else [])
        for n in names:
            per.add_column(f"{n} H", justify="right")
            per.add_column(f"{n} V", justify="right")
        for n in names[:len(segs)]:
            per.add_column(f"{n} NEES", justify="right")
        for i, row in enumerate(segs[0]):
            cells = [row["segment"], f"{row['sats_min']}-{row['sats_max']}"]
            for tab in segs + ([rec_rows] if rec_rows else []):
                rr = tab[i] if i < len(tab) else {}
                cells += [f"{_fmt(rr.get('h_rms'))} ({_fmt(rr.get('h_max'))})",
                          f"{_fmt(rr.get('v_rms'))} ({_fmt(rr.get('v_max'))})"]
            cells += [_fmt((tab[i] if i < len(tab) else {}).get("nees9_mean")) for tab in segs]
            per.add_row(*cells)
        tables.append(per)
    return tables


def outage_table(summary: dict, title: str | None = None):
    """A rich table of one run's drift per outage and the statistics (from run.json's ``scoring``),
    with the smoothed solution's beside the forward one's when the run was smoothed."""
    from rich.table import Table

    sc = summary["scoring"]
    sm = (summary.get("smoothed") or {}).get("scoring")
    if sm is not None and len(sm.get("per_outage", ())) != len(sc["per_outage"]):
        sm = None
    t = Table(title=title or f"{summary.get('mode', '')}: drift against {Path(sc['reference']).name} "
              f"({sc['point']} point), m", title_justify="left")
    names = ["outage", "from (s)", "to (s)", "ref epochs", "max H", "max V"]
    names += ["smooth H", "smooth V"] if sm is not None else []
    for name in names:
        t.add_column(name, justify="left" if name == "outage" else "right")
    both = lambda cells, s_cells: cells + (s_cells if sm is not None else [])  # noqa: E731
    t0 = summary["outages"].get("gnss_first_t", 0.0)  # the schedule's origin: the first GNSS epoch
    for j, o in enumerate(sc["per_outage"]):
        s_o = sm["per_outage"][j] if sm is not None else {}
        t.add_row(*both([str(j + 1), f"{o['start'] - t0:.1f}", f"{o['end'] - t0:.1f}", str(o["n_ref"]),
                         _fmt(o["max_h_m"]), _fmt(o["max_v_m"])],
                        [_fmt(s_o.get("max_h_m")), _fmt(s_o.get("max_v_m"))]))
    for stat in ("mean", "worst", "rms"):
        t.add_row(*both([stat, "", "", "", _fmt(sc["horizontal_m"][stat]), _fmt(sc["vertical_m"][stat])],
                        [_fmt(sm["horizontal_m"][stat]), _fmt(sm["vertical_m"][stat])] if sm else []))
    t.add_row(*both(["outside RMS", "", "", str(sc["outside"]["n"]), _fmt(sc["outside"]["rms_h_m"], 3),
                     _fmt(sc["outside"]["rms_v_m"], 3)],
                    [_fmt(sm["outside"]["rms_h_m"], 3), _fmt(sm["outside"]["rms_v_m"], 3)] if sm else []))
    return t


def print_outage_table(summary: dict, file=None) -> None:
    from rich.console import Console

    Console(file=file, width=None if file is None else 160).print(outage_table(summary))


def print_comparison(paths: list[str | Path], file=None) -> None:
    """The totals and the per-segment table on the terminal (or `file`)."""
    from rich.console import Console

    console = Console(file=file, width=None if file is None else 160)
    for table in comparison_tables(_load_all(paths)):
        console.print(table)


def comparison_table(paths: list[str | Path]) -> str:
    """The same tables as plain text."""
    buf = io.StringIO()
    print_comparison(paths, buf)
    return buf.getvalue()
