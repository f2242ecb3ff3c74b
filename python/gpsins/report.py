"""The evaluation report: the report's chapter 7 figures and a one-page
Markdown summary, from one or more replay results directories (one per
filter mode), side by side when there are several.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy.stats import chi2  # noqa: E402

from . import _core, evaluate  # noqa: E402

KIND_FIX = (1, 2)


@dataclass
class Result:
    name: str
    path: Path
    a: dict
    run: dict

    @property
    def has_truth(self) -> bool:
        return "err_ned_m" in self.a


def load(path: str | Path) -> Result:
    path = Path(path)
    z = np.load(path / "results.npz")
    run = json.loads((path / "run.json").read_text(encoding="utf-8"))
    return Result(run.get("mode", path.name), path, {k: z[k] for k in z.files}, run)


def _local_ned(r: Result, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The solution and the receiver's fixes in NED about `origin` (lat, lon, height)."""
    c = evaluate.c_en(np.array([origin[0]]), np.array([origin[1]]))[0]
    o = _core.geodetic_to_ecef(origin)
    f = r.a["fixes"]
    return (r.a["r_ecef"] - o) @ c, (f[f[:, 9] > 0, 1:4] - o) @ c


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
               "sats_max": int(sats[fm].max()) if fm.any() else 0}
        if m.any():
            h = np.hypot(e[m, 0], e[m, 1])
            row.update(h_rms=float(np.sqrt(np.mean(h ** 2))), h_max=float(h.max()),
                       v_rms=float(np.sqrt(np.mean(e[m, 2] ** 2))), v_max=float(np.abs(e[m, 2]).max()))
        rows.append(row)
    return rows


def _band(ax, t, s, color):
    ax.fill_between(t, -3 * s, 3 * s, color=color, alpha=0.15, lw=0)


def figures(results: list[Result], out: Path) -> list[str]:
    names = []
    base = results[0]
    t0 = base.a["t"][0]
    colors = ["tab:blue", "tab:orange", "tab:green"]

    def save(fig, name):
        fig.tight_layout()
        fig.savefig(out / name, dpi=110)
        plt.close(fig)
        names.append(name)

    # Trajectory in local east-north, fixes, segment labels.
    origin = base.a["llh"][0]
    fig, ax = plt.subplots(figsize=(7, 7))
    for r, c in zip(results, colors):
        ne, fne = _local_ned(r, origin)
        ax.plot(ne[:, 1], ne[:, 0], color=c, lw=1.2, label=f"{r.name} filter")
    ax.plot(fne[:, 1], fne[:, 0], "o", mfc="none", color="tab:green", ms=4, label="receiver fixes")
    if base.has_truth:
        true_ne = _local_ned(base, origin)[0] - base.a["err_ned_m"]
        ax.plot(true_ne[:, 1], true_ne[:, 0], "k--", lw=0.8, label="truth")
        if "seg_t" in base.a:
            for label, (s0, _) in zip(base.a["seg_labels"], base.a["seg_t"]):
                k = np.searchsorted(base.a["t"], s0)
                if k < len(true_ne) and str(label) not in ("Start-A",):
                    ax.annotate(str(label).split("-")[0], true_ne[k, [1, 0]], fontsize=8, color="k")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_aspect("equal", "datalim")
    ax.legend(loc="best", fontsize=8)
    ax.set_title("Trajectory")
    save(fig, "trajectory.png")

    # Position error with 3-sigma bounds (E, N, U).
    if base.has_truth:
        fig, axs = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
        for r, c in zip(results, colors):
            t = r.a["t"] - t0
            e, s = r.a["err_ned_m"], r.a["sigma_ned_m"]
            for ax, i, sign, lab in zip(axs, (1, 0, 2), (1, 1, -1), ("east", "north", "up")):
                _band(ax, t, s[:, i], c)
                ax.plot(t, sign * e[:, i], color=c, lw=0.8, label=r.name)
                ax.set_ylabel(f"{lab} (m)")
        axs[0].legend(fontsize=8)
        axs[0].set_title("Position error (estimate - truth) with 3-sigma bounds")
        axs[-1].set_xlabel("time (s)")
        save(fig, "position_error.png")

    # Innovations of the fix updates with their 3-sigma bounds.
    fig, axs = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    for r, c in zip(results, colors):
        k = np.isin(r.a["upd_kind"], KIND_FIX)
        t = r.a["upd_t"][k] - t0
        for i, ax in enumerate(axs):
            ax.plot(t, r.a["upd_innovation"][k, i], ".", color=c, ms=3, label=r.name)
            ax.plot(t, 3 * r.a["upd_innovation_sigma"][k, i], "-", color=c, lw=0.6)
            ax.plot(t, -3 * r.a["upd_innovation_sigma"][k, i], "-", color=c, lw=0.6)
            ax.set_ylabel(f"{'xyz'[i]} (m)")
    axs[0].set_title("Fix innovations (ECEF; 2D fixes: north, east) with 3-sigma")
    axs[-1].set_xlabel("time (s)")
    save(fig, "innovations.png")

    # Standard deviations.
    fig, axs = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    for r, c in zip(results, colors):
        t = r.a["t"] - t0
        for ax, blk, lab in zip(axs, (r.a["sigma_ypr_deg"], r.a["sigma"][:, 3:6], r.a["sigma_ned_m"]),
                                ("attitude (deg)", "velocity (m/s)", "position (m)")):
            for i, ls in enumerate(("-", "--", ":")):
                ax.plot(t, blk[:, i], ls, color=c, lw=0.9)
            ax.set_ylabel(lab)
            ax.set_yscale("log")
    axs[0].set_title("Standard deviations (N/E/D axes; velocity ECEF x/y/z)")
    axs[-1].set_xlabel("time (s)")
    save(fig, "sigma.png")

    # Attitude with 3-sigma (around the truth when there is one).
    fig, axs = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    for r, c in zip(results, colors):
        t = r.a["t"] - t0
        for ax, i, s_i, lab in zip(axs, (0, 1, 2), (2, 1, 0), ("yaw", "pitch", "roll")):
            y = r.a["ypr_deg"][:, i]
            if r.has_truth:
                ax.plot(t, r.a["err_ypr_deg"][:, i], color=c, lw=0.8, label=r.name)
                _band(ax, t, r.a["sigma_ypr_deg"][:, s_i], c)
                ax.set_ylabel(f"{lab} error (deg)")
                ax.set_ylim(-5 * np.nanmedian(r.a["sigma_ypr_deg"][:, s_i]) - 1, 5 * np.nanmedian(r.a["sigma_ypr_deg"][:, s_i]) + 1)
            else:
                ax.plot(t, y, color=c, lw=0.8, label=r.name)
                ax.set_ylabel(f"{lab} (deg)")
    axs[0].set_title("Attitude" + (" error with 3-sigma" if base.has_truth else ""))
    axs[-1].set_xlabel("time (s)")
    save(fig, "attitude.png")

    # Bias estimates.
    fig, axs = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    for r, c in zip(results, colors):
        t = r.a["t"] - t0
        for i, ls in enumerate(("-", "--", ":")):
            axs[0].plot(t, np.degrees(r.a["gyro_bias"][:, i]) * 3600, ls, color=c, lw=0.9)
            axs[1].plot(t, r.a["accel_bias"][:, i], ls, color=c, lw=0.9)
    axs[0].set_ylabel("gyro bias (deg/h)")
    axs[1].set_ylabel("accel bias (m/s^2)")
    axs[0].set_title("Residual IMU bias estimates (x solid, y dashed, z dotted)")
    axs[-1].set_xlabel("time (s)")
    save(fig, "biases.png")

    # Satellites and DOP.
    f = base.a["fixes"]
    fig, axs = plt.subplots(2, 1, figsize=(10, 5), sharex=True)
    axs[0].step(f[:, 0] - t0, base.a["fix_sats"], where="post")
    axs[0].set_ylabel("satellites used")
    ok = f[:, 9] > 0
    axs[1].plot(f[ok, 0] - t0, f[ok, 7], ".", ms=3, label="HDOP")
    axs[1].plot(f[ok, 0] - t0, np.where(f[ok, 9] == 2, f[ok, 8], np.nan), ".", ms=3, label="VDOP")
    axs[1].set_ylabel("DOP")
    axs[1].legend(fontsize=8)
    axs[-1].set_xlabel("time (s)")
    save(fig, "gnss.png")

    # Consistency: NIS of the fixes and NEES of the navigation states.
    fig, axs = plt.subplots(2 if base.has_truth else 1, 1, figsize=(10, 6), squeeze=False)
    axs = axs[:, 0]
    for r, c in zip(results, colors):
        k = np.isin(r.a["upd_kind"], KIND_FIX)
        axs[0].semilogy(r.a["upd_t"][k] - t0, r.a["upd_nis"][k], ".", color=c, ms=3, label=f"{r.name} NIS")
    lo, hi = chi2.ppf([0.025, 0.975], 3)
    axs[0].axhspan(lo, hi, color="grey", alpha=0.2, label="95 % band, 3 dof")
    axs[0].set_ylabel("NIS")
    axs[0].legend(fontsize=8)
    if base.has_truth:
        for r, c in zip(results, colors):
            axs[1].semilogy(r.a["t"] - t0, r.a["nees9"], color=c, lw=0.6, label=f"{r.name} NEES")
        lo, hi = chi2.ppf([0.025, 0.975], 9)
        axs[1].axhspan(lo, hi, color="grey", alpha=0.2, label="95 % band, 9 dof")
        axs[1].set_ylabel("NEES (9 nav states)")
        axs[1].legend(fontsize=8)
    axs[-1].set_xlabel("time (s)")
    save(fig, "consistency.png")
    return names


def _fmt(x, d=2):
    return "-" if x is None else f"{x:.{d}f}"


def summary_markdown(results: list[Result], figs: list[str]) -> str:
    lines = ["# gpsins replay report", ""]
    for r in results:
        run = r.run
        lines += [f"## {r.name}", "", f"- session: `{Path(run['session']).name}`; IMU samples {run['imu_samples']}; "
                  f"filter wall time {run['wall_time_s']['filter_s']:.2f} s (replay {run['wall_time_s']['total_s']:.2f} s)",
                  f"- alignment: {run['alignment']['method']}, IMU clock {run['alignment']['imu_clock_ppm']:+.1f} ppm, "
                  f"{run['alignment']['imu_frames_missing']} frames missing, clock steps {run['alignment']['clock_steps_s']}",
                  f"- counters: " + ", ".join(f"{k} {v}" for k, v in run["counters"].items() if v),
                  f"- skipped: " + (", ".join(f"{k}: {v}" for k, v in run["skipped"].items()) or "nothing")]
        e = run.get("errors") or {}
        if e:
            lines.append(f"- errors vs truth: horizontal RMS {e['horizontal_rms_m']:.2f} m (max {e['horizontal_max_m']:.2f}), "
                         f"vertical RMS {e['vertical_rms_m']:.2f} m (max {e['vertical_max_m']:.2f}), mean NEES "
                         f"{e['nees9_mean']:.2f} (9 dof), inside 3 sigma {100 * e['inside_3_sigma']:.1f} %")
        lines.append("")
    tables = [(r.name, segment_table(r)) for r in results]
    if any(t for _, t in tables):
        head = "| segment | sats | " + " | ".join(f"{n} H rms / max (m) | {n} V rms / max (m)" for n, _ in tables) + " |"
        lines += ["## Errors per segment", "", head, "|" + "---|" * (2 + 2 * len(tables))]
        for i, row in enumerate(tables[0][1]):
            cells = [row["segment"], f"{row['sats_min']}-{row['sats_max']}"]
            for _, tab in tables:
                rr = tab[i]
                cells += [f"{_fmt(rr.get('h_rms'))} / {_fmt(rr.get('h_max'))}",
                          f"{_fmt(rr.get('v_rms'))} / {_fmt(rr.get('v_max'))}"]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    lines += ["## Figures", ""] + [f"![{f}]({f})" for f in figs] + [""]
    return "\n".join(lines)


def make_report(paths: list[str | Path], out: str | Path) -> Path:
    results = [load(p) for p in paths]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    figs = figures(results, out)
    page = out / "report.md"
    page.write_text(summary_markdown(results, figs), encoding="utf-8")
    return page


def comparison_tables(results: list[Result]) -> list:
    """Rich tables for the terminal: the totals, then the errors per segment (Table 6.1 style)."""
    from rich.table import Table

    totals = Table(title="Errors vs truth", title_justify="left")
    totals.add_column("")
    for r in results:
        totals.add_column(r.name, justify="right")
    for key, lab in (("horizontal_rms_m", "H RMS (m)"), ("horizontal_max_m", "H max (m)"),
                     ("vertical_rms_m", "V RMS (m)"), ("vertical_max_m", "V max (m)"), ("nees9_mean", "mean NEES"),
                     ("inside_3_sigma", "inside 3 sigma (%)")):
        scale = 100.0 if key == "inside_3_sigma" else 1.0
        totals.add_row(lab, *(_fmt(None if (v := (r.run.get("errors") or {}).get(key)) is None else scale * v)
                              for r in results))
    tables = [totals]
    segs = [segment_table(r) for r in results]
    if any(segs):
        per = Table(title="Errors per segment (Table 6.1): RMS (max), m", title_justify="left")
        per.add_column("segment")
        per.add_column("sats", justify="right")
        for r in results:
            per.add_column(f"{r.name} H", justify="right")
            per.add_column(f"{r.name} V", justify="right")
        for i, row in enumerate(segs[0]):
            cells = [row["segment"], f"{row['sats_min']}-{row['sats_max']}"]
            for tab in segs:
                rr = tab[i] if i < len(tab) else {}
                cells += [f"{_fmt(rr.get('h_rms'))} ({_fmt(rr.get('h_max'))})",
                          f"{_fmt(rr.get('v_rms'))} ({_fmt(rr.get('v_max'))})"]
            per.add_row(*cells)
        tables.append(per)
    return tables


def print_comparison(paths: list[str | Path], file=None) -> None:
    """The totals and the per-segment table on the terminal (or `file`)."""
    from rich.console import Console

    console = Console(file=file, width=None if file is None else 160)
    for table in comparison_tables([load(p) for p in paths]):
        console.print(table)


def comparison_table(paths: list[str | Path]) -> str:
    """The same tables as plain text."""
    import io

    buf = io.StringIO()
    print_comparison(paths, buf)
    return buf.getvalue()
