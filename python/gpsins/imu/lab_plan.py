"""The lab plan (TOML) read and checked, its recordings loaded, and their noise analysis.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path


from . import allan, noise_fit, psd, records


OMEGA_E = 7.292115e-5
DEFAULT_REPEATABILITY = {"gyro": 2e-3, "accel": 0.03}  # the `default` preset's turn-on residuals


class PlanError(ValueError):
    pass


@dataclass
class Plan:
    path: Path
    lat_rad: float
    height_m: float
    updown: list[dict]
    rate_table: list[dict]
    drift: dict | None
    analysis: dict = field(default_factory=dict)
    recorded: list = field(default_factory=list)  # (start, end) unix seconds of every recording read


_TOP = {"site", "updown", "rate_table", "drift", "analysis"}
_ENTRY = {"session", "rate_hz", "columns", "start_s", "end_s"}
_KEYS = {"updown": _ENTRY | {"name"},
         "rate_table": _ENTRY | {"axis", "axis_up", "rate_rad_per_s", "turns", "duration_s", "rate_sigma_rad_per_s"},
         "drift": _ENTRY | {"heading_deg", "earth_rate_body_rad_per_s"},
         "analysis": {"taus", "estimator", "min_edf", "confidence", "psd_segment_s", "bias_tau_s",
                      "bias_repeatability_gyro_rad_per_s", "bias_repeatability_accel_mps2"},
         "site": {"lat_deg", "height_m"}}


def load_plan(path: str | Path) -> Plan:
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise PlanError(f"{path}: cannot read ({e.strerror})") from None
    except tomllib.TOMLDecodeError as e:
        raise PlanError(f"{path}: {e}") from None
    bad = set(data) - _TOP
    if bad:
        raise PlanError(f"{path}: unknown table(s) {', '.join(sorted(bad))} (known: {', '.join(sorted(_TOP))})")

    def check(where, table, kind):
        if not isinstance(table, dict):
            raise PlanError(f"{path}: {where} must be a table")
        unknown = set(table) - _KEYS[kind]
        if unknown:
            raise PlanError(f"{path}: {where}: unknown key(s) {', '.join(sorted(unknown))}")
        if kind not in ("site", "analysis") and "session" not in table:
            raise PlanError(f"{path}: {where}: no session")
    site = data.get("site", {})
    check("[site]", site, "site")
    if "lat_deg" not in site:
        raise PlanError(f"{path}: [site]: lat_deg is needed (gravity and Earth rate depend on it)")
    for i, e in enumerate(data.get("updown", [])):
        check(f"[[updown]] {i + 1}", e, "updown")
    for i, e in enumerate(data.get("rate_table", [])):
        where = f"[[rate_table]] {i + 1}"
        check(where, e, "rate_table")
        if e.get("axis") not in ("x", "y", "z"):
            raise PlanError(f"{path}: {where}: axis must be x, y or z")
        if ("rate_rad_per_s" in e) == ("turns" in e):
            raise PlanError(f"{path}: {where}: give rate_rad_per_s (commanded) or turns and duration_s (clocked)")
        if "turns" in e and "duration_s" not in e:
            raise PlanError(f"{path}: {where}: turns needs duration_s")
    drift = data.get("drift")
    if drift is not None:
        check("[drift]", drift, "drift")
    analysis = data.get("analysis", {})
    check("[analysis]", analysis, "analysis")
    if analysis.get("estimator", "overlapping") not in ("overlapping", "non-overlapping"):
        raise PlanError(f"{path}: [analysis]: estimator must be overlapping or non-overlapping")
    return Plan(path, math.radians(site["lat_deg"]), float(site.get("height_m", 0.0)), data.get("updown", []),
                data.get("rate_table", []), drift, analysis)


def load(plan: Plan, entry: dict) -> records.Record:
    src = Path(entry["session"])
    if not src.is_absolute():
        src = plan.path.parent / src
    rec = records.load(src, entry.get("rate_hz"), entry.get("columns"), entry.get("start_s"), entry.get("end_s"),
                       name=str(entry["session"]))
    if rec.start_unix_s is not None:
        plan.recorded.append((rec.start_unix_s, rec.start_unix_s + rec.duration_s))
    return rec

def noise_analysis(rec: records.Record, analysis: dict) -> dict:
    """Allan, fit, read-outs, Gauss-Markov bump and PSD for each column of a static record."""
    taus = analysis.get("taus", 10)
    taus = taus if taus in ("octave", "all", "decade") else int(taus)
    conf = float(analysis.get("confidence", 0.683))
    min_edf = float(analysis.get("min_edf", noise_fit.MIN_EDF))
    estimator = analysis.get("estimator", "overlapping")
    out = {}
    for k, name in enumerate(rec.columns):
        y = rec.rates[:, k]
        if estimator == "overlapping":
            r = allan.oadev(y, rec.rate_hz, taus=taus, confidence=conf)
        else:
            r = allan.adev_nonoverlapping(y, rec.rate_hz, taus=taus, confidence=conf)
        terms = ("Q", "N", "B", "K")
        bump = noise_fit.gauss_markov_bump(r.tau, r.adev, r.lo, r.hi, r.edf, min_edf)
        f = noise_fit.fit(r.tau, r.adev, r.edf, terms=terms, gm_tau_s=(bump["T_s"],) if bump else (),
                          min_edf=min_edf)
        fr, p = psd.psd(y, rec.rate_hz, float(analysis.get("psd_segment_s", 100.0)))
        fc, pc = psd.log_average(fr, p)
        n_psd = float(psd.white_level(fr, p))
        out[name] = {"y": y, "allan": r, "fit": f, "bump": bump, "psd": (fr, p, fc, pc), "N_psd": n_psd,
                     "short_taus": int((r.edf < min_edf).sum())}
    return out


def noise_value(noise: dict | None, name: str) -> dict | None:
    return None if noise is None or name not in noise else noise[name]["fit"].value
