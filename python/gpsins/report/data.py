"""The report's data: replay results loaded (``Result``, ``load``: the results tables, a long run's
epochs decimated, and ``run.json``), and the numbers the page and the figures show: errors per
segment, the receiver's errors, innovation intervals, the truth's residual biases, satellite
visibility, and the one time origin every figure and table counts from (``time_origin``).
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import _core, evaluate
from ..replay import results
from ..formats.gpstime import SECONDS_PER_WEEK


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


def load_all(paths) -> list[Result]:
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


def stats(e: np.ndarray) -> dict:
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
    from ..formats.truth import open_truth  # memory-mapped: only the receiver epochs' rows are read

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
        row.update(stats(e[m]))
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
    return [{"segment": str(label), **stats(e[(t >= t0) & (t < t1)])}
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


def truth_file(r: Result) -> dict | None:
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

    from ..session import logs, measurements

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
