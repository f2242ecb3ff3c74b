"""The evaluation report: the report's chapter 7 figures, a Markdown page and
the same page as one self-contained HTML file (figures embedded), from one or
more replay results directories (one per filter mode), side by side.

Figures are built by ``build_figures`` (matplotlib Figure objects, so tests can
inspect what each panel holds; drawn in ``report_figures``) and written by
``figures``. Everything comes from the results tables (``results.load``; a long
run's epochs decimated) and ``run.json``; the truth's biases and clock and the
satellites' visibility and sky tracks come from the session's files
(``truth.npz`` and the receiver's ID 23 and ID 22) when they are still there.
Every time, in figures and tables, counts from one origin (``time_origin``).
"""

from __future__ import annotations

import base64
import html
import io
import json
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import _core, evaluate
from .nav import noise_from_data
from .replay import results
from .formats.gpstime import SECONDS_PER_WEEK

# Replay imports this module for its outage table: the figures (matplotlib) are imported where drawn.

KIND_FIX3, KIND_FIX2, KIND_PR, KIND_RR = 1, 2, 6, 9
KIND_NAMES = {KIND_FIX3: "3D fix", KIND_FIX2: "2D fix", KIND_PR: "pseudorange", KIND_RR: "range rate"}
PER_SATELLITE = (KIND_PR, KIND_RR)
MODE_COLORS = {"loose": "tab:blue", "tight": "tab:orange", "ins": "tab:red"}
OTHER_COLORS = ("tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:gray", "k", "tab:green", "y", "m", "c")
RECEIVER_COLOR = "tab:green"
AXIS_STYLES = ("-", "--", ":")


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


def load(path: str | Path, max_epochs: int = MAX_PLOT_EPOCHS, name: str | None = None) -> Result:
    """A run's results; named ``name`` (the user's), else by its mode, plug-in estimator and stretch."""
    path = Path(path)
    stride = max(1, -(-results.epochs(path) // max_epochs))
    a = results.load(path, stride=stride)
    run = json.loads((path / "run.json").read_text(encoding="utf-8"))
    cfg_path = path / "config.toml"
    cfg = tomllib.loads(cfg_path.read_text(encoding="utf-8")) if cfg_path.exists() else {}
    mode = run.get("mode", path.name)
    if name is None:
        name = mode
        if run.get("estimator"):
            name += " " + str(run["estimator"]).rpartition(".")[2]
        if run.get("stretch"):
            name += f" stretch {run['stretch']['index']}"
    color = MODE_COLORS.get(mode, "tab:blue") if not run.get("estimator") else OTHER_COLORS[0]
    return Result(name, path, a, run, color, cfg)


def named(arg: str) -> tuple[str | None, str]:
    """``NAME=RESULTS`` -> (NAME, RESULTS); a plain RESULTS has no name of its own."""
    head, sep, tail = arg.partition("=")
    return (head, tail) if sep and head and "/" not in head else (None, arg)


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
    forward and smoothed side by side. The smoother makes no updates: the companion has none (the forward
    run's would be drawn and counted twice)."""
    keys = [k for k in r.a if k.startswith("smooth_")]
    if not keys or r.name.endswith(" smoothed"):
        return None
    a = {k: v[:0] if k.startswith("upd_") else v for k, v in r.a.items() if not k.startswith("smooth_")}
    a.update({k[len("smooth_"):]: r.a[k] for k in keys})
    sm = r.run.get("smoothed") or {}
    run = dict(r.run, errors=sm.get("errors", {}), mode=f"{r.name} smoothed")
    if sm.get("scoring"):
        run["scoring"] = {**(r.run.get("scoring") or {}), **sm["scoring"]}
    return Result(f"{r.name} smoothed", r.path, a, run, "tab:cyan", r.config)


def _load_all(paths) -> list[Result]:
    """Results from directories, (directory, name) pairs or loaded Results."""
    results = [p if isinstance(p, Result) else load(p[0], name=p[1]) if isinstance(p, tuple) else load(p)
               for p in paths]
    names = {r.name for r in results}
    results = [x for r in results for x in (r, None if f"{r.name} smoothed" in names else smoothed_companion(r))
               if x is not None]
    used = set()
    for r in results:  # two runs of the same mode get different colours (cycled past ten)
        if r.color in used:
            free = [c for c in OTHER_COLORS if c not in used]
            r.color = free[0] if free else OTHER_COLORS[len(used) % len(OTHER_COLORS)]
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


def fix_true_times(r: Result) -> np.ndarray:
    """The receiver's fixes on the truth's time line (the segments'). A fix's time is the receiver's tag, which
    runs ahead of GPS time by the receiver clock's bias: a simulated fix tagged 31.0 was measured tens of ns
    before 31 s, before a segment (and its obstructions) starting at 31 s. Going by the tags, the segment table
    counted that fix, with the satellites of the segment before, in the one that starts there (A-B "4-8" where
    the fixes measured in A-B have 4). With the session's truth, each fix's tag less the clock bias at its epoch;
    the tags themselves otherwise."""
    f_t = r.a["fixes"][:, 0]
    s = r.session
    p = next((q for q in ((s / "truth.npz", s.parent / "truth.npz") if s is not None else ()) if q.exists()), None)
    if p is None or not len(f_t):
        return f_t
    from .formats.truth import open_truth  # memory-mapped: only the receiver epochs' rows are read

    z = open_truth(p)
    if "clock_bias_s" not in z or not len(z["gnss_t"]):
        return f_t
    start = float(z["t0_tow_s"]) + (int(z["gps_week"]) - int(r.a["week"])) * SECONDS_PER_WEEK
    bias = np.asarray(z["clock_bias_s"], float)
    return f_t - np.interp(f_t - start, np.asarray(z["gnss_t"], float) + bias, bias)


def segment_table(r: Result) -> list[dict]:
    """RMS and maximum horizontal and vertical error per truth segment (Table 6.1 style)."""
    if not r.has_truth or "seg_t" not in r.a:
        return []
    t, e, hk = r.a["t"], r.a["err_ned_m"], r.a["heading_known"]
    f_t, sats = fix_true_times(r), r.a["fix_sats"]
    rows = []
    for label, (t0, t1) in zip(r.a["seg_labels"], r.a["seg_t"]):
        m = (t >= t0) & (t < t1) & hk & np.isfinite(e[:, 0])
        fm = (f_t >= t0) & (f_t < t1)
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

    from .session import logs, measurements

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


# ---------------------------------------------------------------- time


def _origin(r: Result) -> tuple[float, str]:
    first = (r.run.get("outages") or {}).get("gnss_first_t")
    if first is None and len(r.a["fixes"]):
        first = r.a["fixes"][0, 0]
    return (float(r.a["t"][0]), "the first epoch") if first is None else (float(first), "the first GNSS epoch")


def time_origin(r: Result) -> float:
    """The report's one time origin, in the results' time: the first GNSS epoch (where --outages counts
    from and the drift table's times start), else the first epoch."""
    return _origin(r)[0]


def time_origin_text(r: Result) -> str:
    """The origin as every time axis and the page state it."""
    t0, what = _origin(r)
    week = int(r.a["week"]) + int(t0 // SECONDS_PER_WEEK)
    return f"s since {what}, GPS week {week} tow {t0 % SECONDS_PER_WEEK:.2f} s"


def shows_outage_table(run: dict) -> bool:
    """Worth a table of its own: outages were scored, or the reference is a file (not the session's truth,
    whose errors the truth tables already give)."""
    sc = run.get("scoring") or {}
    return bool(sc) and (sc.get("n_outages", 0) > 0 or sc.get("point") == "antenna")


# ---------------------------------------------------------------- figures (report_figures)


def build_figures(results: list) -> dict:
    """Every figure of the report, by file name (matplotlib Figures); the caller saves or inspects and
    closes them."""
    from . import report_figures

    return report_figures.build_figures(_load_all(results))


def figures(results: list[Result], out: Path) -> list[str]:
    """Write every figure as PNG into `out`; returns the file names."""
    from . import report_figures

    return report_figures.figures(_load_all(results), out)


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
    t0 = time_origin(results[0])
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
    mean, worst and RMS of the per-outage maxima and the RMS outside outages: (title, header, rows); times
    from t0, the report's origin."""
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


def _times_line(results: list[Result]) -> str:
    return f"Times in the tables and figures: {time_origin_text(results[0])}."


def _captions(results: list[Result], figs: list[str]) -> list[tuple[str, str, str]]:
    """(file, short name, caption) per figure."""
    from . import report_figures

    caps = report_figures.figure_captions(results)
    return [(f, f.removesuffix(".png").replace("_", " "), caps.get(f, "")) for f in figs]


def summary_markdown(results: list[Result], figs: list[str]) -> str:
    results = _load_all(results)
    lines = ["# gpsins replay report", ""]
    lines += [f"**WARNING: {w}**" for w in _warning_lines(results)] + ([""] if _warning_lines(results) else [])
    for r in results:
        lines += [f"## {r.name}", ""] + [f"- {x}" for x in _run_lines(r) + noise_from_data.summary_lines(r.run)] + [""]
    rec = _receiver_line(results[0])
    if rec:
        lines += [f"- {rec}", ""]
    lines += [_times_line(results), ""]
    for title, head, rows in page_tables(results):
        lines += [f"## {title}", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        lines += ["| " + " | ".join(c) + " |" for c in rows] or ["| none |" + " |" * (len(head) - 1)]
        lines.append("")
    lines += ["## Figures", ""]
    for k, (f, name, cap) in enumerate(_captions(results, figs), 1):
        lines += [f"![{name}]({f})", "", f"*Figure {k} ({name}).* {cap}", ""]
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
    parts.append(f"<p>{esc(_times_line(results))}</p>")
    for title, head, rows in page_tables(results):
        parts.append(f"<h2>{esc(title)}</h2><table><tr>" + "".join(f"<th>{esc(h)}</th>" for h in head) + "</tr>")
        parts += ["<tr>" + "".join(f"<td>{esc(c)}</td>" for c in row) + "</tr>" for row in rows]
        parts.append("</table>" + ("" if rows else "<p>none</p>"))
    parts.append("<h2>Figures</h2>")
    for k, (f, name, cap) in enumerate(_captions(results, figs), 1):
        data = base64.b64encode((fig_dir / f).read_bytes()).decode("ascii")
        parts.append(f'<figure><img alt="{esc(name)}" src="data:image/png;base64,{data}"><figcaption>'
                     f"<b>Figure {k} ({esc(name)}).</b> {esc(cap)}</figcaption></figure>")
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
    """Rich tables for the terminal: the totals, then the errors per segment (Table 6.1 style), a table
    per run and one for the receiver's fixes, each within TERMINAL_WIDTH."""
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
    if any(segs):  # one table per run, the receiver's last: side by side they need 140 columns
        rec_rows = receiver_segment_table(results[0])
        tables += [_segment_rich_table(f"{r.name}: errors per segment (Table 6.1)", rows, nees=True)
                   for r, rows in zip(results, segs) if rows]
        if rec_rows:
            sats = {row["segment"]: {k: row[k] for k in ("sats_min", "sats_max")} for row in segs[0]}
            tables.append(_segment_rich_table("receiver fixes: errors per segment (Table 6.1)",
                                              [{**x, **sats.get(x["segment"], {})} for x in rec_rows], nees=False))
    return tables


def _segment_rich_table(title: str, rows: list[dict], nees: bool):
    """One run's errors per segment: RMS (max) horizontal and vertical, and its mean NEES."""
    from rich.table import Table

    t = Table(title=title, title_justify="left")
    for name in ("segment", "sats", "H RMS (max), m", "V RMS (max), m") + (("NEES",) if nees else ()):
        t.add_column(name, justify="left" if name == "segment" else "right")
    for row in rows:
        sats = f"{row['sats_min']}-{row['sats_max']}" if "sats_min" in row else ""
        t.add_row(row["segment"], sats, f"{_fmt(row.get('h_rms'))} ({_fmt(row.get('h_max'))})",
                  f"{_fmt(row.get('v_rms'))} ({_fmt(row.get('v_max'))})",
                  *([_fmt(row.get("nees9_mean"))] if nees else []))
    return t


def outage_table(summary: dict, title: str | None = None):
    """A rich table of one run's drift per outage and the statistics (from run.json's ``scoring``),
    with the smoothed solution's beside the forward one's when the run was smoothed."""
    from rich.table import Table

    sc = summary["scoring"]
    sm = (summary.get("smoothed") or {}).get("scoring")
    if sm is not None and len(sm.get("per_outage", ())) != len(sc["per_outage"]):
        sm = None
    t = Table(title=title or f"{summary.get('mode', '')}: drift against {Path(sc['reference']).name} "
              f"({sc['point']} point), m", title_justify="left",
              caption="from, to: s since the first GNSS epoch", caption_justify="left")
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


TERMINAL_WIDTH = 100  # the terminal tables fit it; a log file is written at it (rich would take 80)


def _console(file=None):
    """A rich console at the terminal's width, or TERMINAL_WIDTH for a file or a pipe."""
    from rich.console import Console

    to_terminal = file is None and sys.stdout.isatty()
    return Console(file=file, width=None if to_terminal else TERMINAL_WIDTH)


def print_outage_table(summary: dict, file=None) -> None:
    _console(file).print(outage_table(summary))


def print_comparison(paths: list[str | Path], file=None) -> None:
    """The totals and the per-segment tables on the terminal (or `file`)."""
    console = _console(file)
    for table in comparison_tables(_load_all(paths)):
        console.print(table)


def comparison_table(paths: list[str | Path]) -> str:
    """The same tables as plain text."""
    buf = io.StringIO()
    print_comparison(paths, buf)
    return buf.getvalue()
