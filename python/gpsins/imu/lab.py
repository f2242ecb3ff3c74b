"""The IMU laboratory workflow of the FOI report, chapter 5, from recorded sessions.

A lab plan (TOML) names the recordings and what each is:

    [site]            lat_deg, height_m
    [[updown]]        session (dir, or file with rate_hz and columns), optional start_s / end_s;
                      any number of static positions per session (up-down pairs or the six positions):
                      each steady window is classified by which accelerometer axis sees +g or -g
    [[rate_table]]    session, axis, axis_up (default true), and either rate_rad_per_s (commanded)
                      or turns + duration_s (clocked), optional rate_sigma_rad_per_s
    [drift]           session, heading_deg (level, z down) or earth_rate_body_rad_per_s
    [analysis]        taus, estimator (overlapping | non-overlapping), min_edf, confidence,
                      psd_segment_s, bias_repeatability_gyro_rad_per_s, bias_repeatability_accel_mps2

Estimates (SI inside):
- up-down (eq. 5.2 corrected): b = (z_up + z_down) / 2, s = (z_up - z_down - 2 g) / (2 g), g the WGS-84
  normal gravity of the site. b's uncertainty is the white noise of the two window means (their
  sample statistics); s's adds the bias's wander between the windows, the variance of the difference of
  the two window means under the noise terms fitted to the drift run (noise_fit.window_combination_variance).
- rate table (eq. 5.3-5.5 corrected): a weighted line through (table rate + Earth rate, mean output);
  each point's variance = its window's white noise + the bias's wander (same model) + the rate's own
  uncertainty; the widest opposite-sign pair gives the report's eq. 5.4 / 5.5 numbers next to it.
- drift test: gyro bias = mean output - (1 + s) x Earth rate along the axis (site latitude, heading).
- noise (drift run): Allan deviation with chi-square and eq. 5.9 bounds, fitted Q N B K, slope read-outs
  only at taus with edf >= min_edf, a Gauss-Markov read-out when the curve has a significant bump,
  Welch PSD with frequency averaging and its white level; Table 5.10 compares the two N.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..replay import results
from . import allan, calibration, noise_fit, psd, records
from .records import AXES, RecordError

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


def _load(plan: Plan, entry: dict) -> records.Record:
    src = Path(entry["session"])
    if not src.is_absolute():
        src = plan.path.parent / src
    rec = records.load(src, entry.get("rate_hz"), entry.get("columns"), entry.get("start_s"), entry.get("end_s"),
                       name=str(entry["session"]))
    if rec.start_unix_s is not None:
        plan.recorded.append((rec.start_unix_s, rec.start_unix_s + rec.duration_s))
    return rec


# --- noise ----------------------------------------------------------------------------------------------

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


def _noise_value(noise: dict | None, name: str) -> dict | None:
    return None if noise is None or name not in noise else noise[name]["fit"].value


# --- deterministic calibration --------------------------------------------------------------------------

def _window_stats(y: np.ndarray, rate_hz: float, white: dict | None = None) -> tuple[float, float, int]:
    """Mean, its white-noise uncertainty and the sample count of a window. The error of the mean
    against the bias's own mean over the window is the white part only: with the drift run's fitted
    N it is N / sqrt(T); without, the sample standard deviation / sqrt(n) (which also holds the
    wander inside the window, so it errs on the large side)."""
    if white is not None and white.get("N", 0.0) > 0:
        return float(y.mean()), float(white["N"] / math.sqrt(len(y) / rate_hz)), len(y)
    return float(y.mean()), float(y.std(ddof=1) / math.sqrt(len(y))), len(y)


def _classify(mean_acc: np.ndarray, g: float) -> tuple[int, int, float]:
    """(axis, sign, tilt of that axis from the vertical in rad) of a static window's gravity reading."""
    i = int(np.argmax(np.abs(mean_acc)))
    tilt = math.atan2(float(np.hypot(*np.delete(mean_acc, i))), abs(float(mean_acc[i])))
    return i, int(np.sign(mean_acc[i])), tilt


def updown(plan: Plan, noise: dict | None, warnings: list) -> dict:
    g = calibration.local_gravity_mps2(plan.lat_rad, plan.height_m)
    positions = []  # (axis, sign, mean, sigma_white, n, start_s on the common line, length_s, source, window)
    for entry in plan.updown:
        rec = _load(plan, entry)
        warnings.extend(f"{rec.name}: {n}" for n in rec.notes)
        st = records.steady_windows(rec.rates, rec.rate_hz)
        t0 = rec.start_unix_s or 0.0
        for a, b in st.windows:
            acc = rec.rates[a:b, 3:6].mean(0)
            i, sign, tilt = _classify(acc, g)
            if abs(acc[i]) < 0.5 * g:
                warnings.append(f"{rec.name}: window {a / rec.rate_hz:.0f}-{b / rec.rate_hz:.0f} s sees no gravity "
                                f"along an axis ({acc.round(2).tolist()} m/s^2): skipped")
                continue
            if tilt > math.radians(5):
                warnings.append(f"{rec.name}: window {a / rec.rate_hz:.0f}-{b / rec.rate_hz:.0f} s: accel {'xyz'[i]} "
                                f"is {math.degrees(tilt):.1f} deg off the vertical (not levelled): skipped")
                continue
            m, s, n = _window_stats(rec.rates[a:b, 3 + i], rec.rate_hz, _noise_value(noise, f"accel_{'xyz'[i]}"))
            positions.append(dict(axis=i, sign=sign, mean=m, sigma=s, n=n, start=t0 + a / rec.rate_hz,
                                  length=(b - a) / rec.rate_hz, source=rec.name, window_s=[a / rec.rate_hz,
                                                                                            b / rec.rate_hz],
                                  tilt_rad=tilt))
    out = {"gravity_mps2": g, "axes": {}}
    for i, a in enumerate("xyz"):
        ups = [p for p in positions if p["axis"] == i and p["sign"] > 0]
        dns = [p for p in positions if p["axis"] == i and p["sign"] < 0]
        if not ups or not dns:
            if ups or dns:
                warnings.append(f"up-down: no {'up' if not ups else 'down'} position of accelerometer {a}")
            continue
        # The closest up and down windows in time: least bias wander between them.
        u, d = min(((u, d) for u in ups for d in dns), key=lambda ud: abs(ud[0]["start"] - ud[1]["start"]))
        c = calibration.accel_up_down(u["mean"], d["mean"], g)
        sig_b = 0.5 * math.hypot(u["sigma"], d["sigma"])
        value = _noise_value(noise, f"accel_{a}")
        white = math.hypot(u["sigma"], d["sigma"]) ** 2
        if value is not None:
            first, second = sorted((u, d), key=lambda p: p["start"])
            model = noise_fit.window_combination_variance(
                value, noise[f"accel_{a}"]["allan"].tau0, [(first["start"], first["length"], 1.0),
                                                          (second["start"], second["length"], -1.0)])
            emp, indep = pair_difference_variance(noise[f"accel_{a}"]["y"], 1.0 / noise[f"accel_{a}"]["allan"].tau0,
                                                  first["length"], second["start"] - first["start"] - first["length"],
                                                  second["length"])
            if indep >= MIN_INDEPENDENT_PAIRS:
                var = emp
                basis = (f"difference of two such window means slid along the drift run ({indep:.0f} independent "
                         f"pairs; the fitted noise terms give {math.sqrt(model) / (2 * g):.1e})")
            else:
                var = model
                basis = (f"difference of the two window means under the drift run's fitted noise terms (the run "
                         f"holds only {indep:.0f} independent pairs of such windows)")
        else:
            var = white
            basis = "white noise of the windows only (no drift run): a lower bound"
        sig_s = math.sqrt(var) / (2 * g)
        best = _best_position_length(value, noise[f"accel_{a}"]["allan"].tau0, abs(d["start"] - u["start"]) -
                                     u["length"], g) if value is not None else None
        out["axes"][a] = {"bias_mps2": c.bias, "bias_sigma_mps2": sig_b, "scale_factor": c.scale_factor,
                          "scale_factor_sigma": sig_s, "best_position_s": best,
                          "z_up_mps2": u["mean"], "z_down_mps2": d["mean"],
                          "up": {k: u[k] for k in ("source", "window_s", "n", "sigma", "tilt_rad")},
                          "down": {k: d[k] for k in ("source", "window_s", "n", "sigma", "tilt_rad")},
                          "uncertainty_basis": basis}
    return out


MIN_INDEPENDENT_PAIRS = 10


def pair_difference_variance(y: np.ndarray, rate_hz: float, first_s: float, gap_s: float,
                             second_s: float) -> tuple[float, float]:
    """Mean square of (mean over a window of first_s) - (mean over a window of second_s starting gap_s
    after it), slid sample by sample along a static record y: the sample statistic of the up-down
    difference's wander. Returns it and the number of independent (disjoint) placements."""
    n1, n2 = max(1, int(round(first_s * rate_hz))), max(1, int(round(second_s * rate_hz)))
    ng = max(0, int(round(gap_s * rate_hz)))
    span = n1 + ng + n2
    if span >= len(y):
        return float("nan"), 0.0
    c = np.concatenate([[0.0], np.cumsum(y - y.mean())])
    s = np.arange(len(y) - span + 1)
    d = (c[s + n1] - c[s]) / n1 - (c[s + span] - c[s + n1 + ng]) / n2
    return float(np.mean(d * d)), len(y) / span


def _best_position_length(value: dict, tau0: float, gap_s: float, g: float) -> dict:
    """The position length that minimises the scale factor's uncertainty under the drift run's noise:
    longer positions average white noise down, but the bias wanders further between them."""
    gap = max(gap_s, 0.0)
    lengths = np.logspace(0.5, 3.6, 32)
    sig = [math.sqrt(noise_fit.window_combination_variance(value, tau0, [(0.0, T, 1.0), (T + gap, T, -1.0)])) / (2 * g)
           for T in lengths]
    k = int(np.argmin(sig))
    return {"length_s": float(lengths[k]), "scale_factor_sigma": float(sig[k])}


def _table_rate(entry: dict) -> tuple[float, float]:
    if "rate_rad_per_s" in entry:
        w = float(entry["rate_rad_per_s"])
        return w, float(entry.get("rate_sigma_rad_per_s", 0.0))
    dur = float(entry["duration_s"])
    w = 2 * math.pi * float(entry["turns"]) / dur
    # Clocking by hand: the default timing error is 0.2 s on the stopwatch.
    return w, float(entry.get("rate_sigma_rad_per_s", abs(w) * 0.2 / dur))


def rate_table(plan: Plan, noise: dict | None, drift_bias: dict | None, warnings: list) -> dict:
    runs = {a: [] for a in "xyz"}
    for entry in plan.rate_table:
        rec = _load(plan, entry)
        warnings.extend(f"{rec.name}: {n}" for n in rec.notes)
        a = entry["axis"]
        i = "xyz".index(a)
        st = records.steady_windows(rec.rates, rec.rate_hz)
        if not st.windows:
            warnings.append(f"{rec.name}: no steady stretch (the table rate never settled): skipped")
            continue
        lo, hi = max(st.windows, key=lambda w: w[1] - w[0])
        w, w_sig = _table_rate(entry)
        m, s, n = _window_stats(rec.rates[lo:hi, i], rec.rate_hz, _noise_value(noise, f"gyro_{a}"))
        if np.sign(m) != np.sign(w) and abs(w) > 0.05:
            warnings.append(f"{rec.name}: gyro {a} reads {m:+.4f} rad/s against a table rate of {w:+.4f}: check "
                            f"the axis and the sign convention")
        runs[a].append(dict(rate=w, rate_sigma=w_sig, mean=m, sigma=s, n=n, source=rec.name,
                            start=(rec.start_unix_s or 0.0) + lo / rec.rate_hz, length=(hi - lo) / rec.rate_hz,
                            window_s=[lo / rec.rate_hz, hi / rec.rate_hz], axis_up=bool(entry.get("axis_up", True))))
    out = {"axes": {}}
    for a, rs in runs.items():
        if len(rs) < 2:
            if rs:
                warnings.append(f"rate table: gyro {a} has {len(rs)} run; two rates are needed for a scale factor")
            continue
        w_ex = calibration.earth_rate_component(plan.lat_rad, rs[0]["axis_up"]) if rs[0]["axis_up"] else 0.0
        x = np.array([r["rate"] for r in rs]) + w_ex
        y = np.array([r["mean"] for r in rs])
        value = _noise_value(noise, f"gyro_{a}")
        t0 = min(r["start"] for r in rs)
        t1 = max(r["start"] + r["length"] for r in rs)
        # Each run's mean about the mean over all runs of the axis: white noise and the bias's wander,
        # correlated from run to run (a wander that trends through a sequence of rising rates would
        # otherwise pass for a scale factor), plus each table rate's own uncertainty.
        if value is not None:
            combos = [[(r["start"], r["length"], 1.0), (t0, t1 - t0, -1.0)] for r in rs]
            cov_e = noise_fit.window_combination_covariance(value, noise[f"gyro_{a}"]["allan"].tau0, combos)
        else:
            cov_e = np.diag([r["sigma"] ** 2 for r in rs])
        cov_e = cov_e + np.diag([r["rate_sigma"] ** 2 for r in rs])
        A = np.column_stack([np.ones_like(x), x])
        ci = np.linalg.inv(cov_e)
        cov = np.linalg.inv(A.T @ ci @ A)
        b, slope = cov @ (A.T @ ci @ y)
        resid = y - A @ np.array([b, slope])
        chi2_dof = float(resid @ ci @ resid / max(len(x) - 2, 1))
        entry = {"scale_factor": float(slope - 1), "scale_factor_sigma": float(math.sqrt(cov[1, 1])),
                 "bias_rad_per_s": float(b), "bias_sigma_rad_per_s": float(math.sqrt(cov[0, 0])),
                 "chi2_per_dof": chi2_dof, "earth_rate_along_axis_rad_per_s": w_ex,
                 "runs": [{k: r[k] for k in ("rate", "rate_sigma", "mean", "sigma", "source", "window_s")} for r in rs],
                 "uncertainty_basis": "generalised least squares; the runs' white noise and correlated bias wander "
                                      "(drift-run noise terms) + table-rate uncertainty" if value is not None else
                                      "weighted line; white noise + table-rate uncertainty only (no drift run)"}
        # The report's pairwise form (eq. 5.4, corrected eq. 5.5) on the widest opposite-sign pair.
        pos, neg = [r for r in rs if r["rate"] > 0], [r for r in rs if r["rate"] < 0]
        if pos and neg:
            p, q = max(pos, key=lambda r: r["rate"]), min(neg, key=lambda r: r["rate"])
            s54 = ((p["mean"] - q["mean"]) - (p["rate"] - q["rate"])) / (p["rate"] - q["rate"])
            b55 = (p["mean"] + q["mean"]) / 2 - (s54 + 1) * ((p["rate"] + q["rate"]) / 2 + w_ex)
            entry["pair_eq_5_4_5_5"] = {"rates": [p["rate"], q["rate"]], "scale_factor": s54, "bias_rad_per_s": b55}
        if drift_bias and a in drift_bias:
            entry["bias_from_drift_test_rad_per_s"] = drift_bias[a]["bias_rad_per_s"]
        out["axes"][a] = entry
    return out


def earth_rate_body(plan: Plan) -> np.ndarray:
    d = plan.drift or {}
    if "earth_rate_body_rad_per_s" in d:
        return np.asarray(d["earth_rate_body_rad_per_s"], dtype=float)
    psi = math.radians(float(d.get("heading_deg", 0.0)))
    w_n = OMEGA_E * np.array([math.cos(plan.lat_rad), 0.0, -math.sin(plan.lat_rad)])
    c_nb = np.array([[math.cos(psi), -math.sin(psi), 0.0], [math.sin(psi), math.cos(psi), 0.0], [0.0, 0.0, 1.0]])
    return c_nb.T @ w_n


def drift_test(plan: Plan, rec: records.Record, window: tuple[int, int], scale: dict, noise: dict | None) -> dict:
    w_b = earth_rate_body(plan)
    out = {}
    a0, a1 = window
    for i, a in enumerate("xyz"):
        m, s, n = _window_stats(rec.rates[a0:a1, i], rec.rate_hz, _noise_value(noise, f"gyro_{a}"))
        sf = scale.get(a, 0.0)
        out[a] = {"bias_rad_per_s": m - (1 + sf) * w_b[i], "bias_sigma_rad_per_s": s, "mean_output_rad_per_s": m,
                  "earth_rate_rad_per_s": float(w_b[i]), "window_s": [a0 / rec.rate_hz, a1 / rec.rate_hz]}
    return out


# --- the whole plan ---------------------------------------------------------------------------------------

def run_plan(plan: Plan) -> dict:
    """Everything the plan asks for, as one result dictionary (arrays kept for the report)."""
    warnings: list[str] = []
    res: dict = {"plan": str(plan.path.name),
                 "site": {"lat_deg": math.degrees(plan.lat_rad), "height_m": plan.height_m},
                 "min_edf": float(plan.analysis.get("min_edf", noise_fit.MIN_EDF)),
                 "estimator": plan.analysis.get("estimator", "overlapping"), "warnings": warnings}
    noise = drift_rec = None
    window = None
    if plan.drift:
        drift_rec = _load(plan, plan.drift)
        warnings.extend(f"{drift_rec.name}: {n}" for n in drift_rec.notes)
        st = records.steady_windows(drift_rec.rates, drift_rec.rate_hz, min_s=10.0)
        msg = records.motion_warning(st, drift_rec.duration_s)
        if msg:
            warnings.append(f"drift run {drift_rec.name}: {msg}")
        if st.windows:
            window = max(st.windows, key=lambda w: w[1] - w[0])
            static = records.Record(drift_rec.name, drift_rec.rates[window[0]:window[1]], drift_rec.rate_hz,
                                    drift_rec.columns, (drift_rec.start_unix_s or 0.0) + window[0] / drift_rec.rate_hz)
            if st.moved:
                warnings.append(f"drift run: noise terms from its longest static window "
                                f"{window[0] / drift_rec.rate_hz:.0f}-{window[1] / drift_rec.rate_hz:.0f} s only")
            noise = noise_analysis(static, plan.analysis)
            res["drift_window_s"] = [window[0] / drift_rec.rate_hz, window[1] / drift_rec.rate_hz]
            span = (window[1] - window[0]) / drift_rec.rate_hz
            usable = max(float(v["allan"].tau[v["allan"].edf >= res["min_edf"]].max(initial=0.0))
                         for v in noise.values())
            if span < 3600.0:
                warnings.append(f"drift run: {span / 60:.0f} min static; taus with at least {res['min_edf']:g} degrees "
                                f"of freedom reach only {usable:.0f} s, so bias instability and rate random walk rest on "
                                f"few points (the report used 50 min; hours are better)")
            for name, v in noise.items():
                if "warning" in v["fit"].slope_readouts:
                    warnings.append(f"{name}: {v['fit'].slope_readouts['warning']}")
            for name, v in noise.items():
                if v["short_taus"]:
                    warnings.append(f"{name}: {v['short_taus']} of {len(v['allan'].tau)} taus have fewer than "
                                    f"{res['min_edf']:g} degrees of freedom: plotted, fitted with their weight, "
                                    f"not used for slope read-outs")
                    break
    res["noise"] = noise
    res["updown"] = updown(plan, noise, warnings) if plan.updown else None
    if res["updown"] and len(res["updown"]["axes"]) < 3:
        missing = sorted(set("xyz") - set(res["updown"]["axes"]))
        warnings.append(f"up-down: accelerometer(s) {', '.join(missing)} not calibrated: the preset keeps the "
                        f"default's accelerometer calibration")
    rt = rate_table(plan, noise, None, warnings) if plan.rate_table else None
    scale = {a: v["scale_factor"] for a, v in (rt or {"axes": {}})["axes"].items()}
    res["drift"] = drift_test(plan, drift_rec, window, scale, noise) if window else None
    if rt and res["drift"]:
        for a, v in rt["axes"].items():
            v["bias_from_drift_test_rad_per_s"] = res["drift"][a]["bias_rad_per_s"]
    res["rate_table"] = rt
    rec = plan.recorded
    res["day_span_s"] = (max(e for _, e in rec) - min(s for s, _ in rec)) if rec else 0.0
    return res


# --- what the filter and Kalibr read ----------------------------------------------------------------------

def calibration_table(res: dict, plan: Plan) -> dict:
    """Filter configuration keys (a preset load_config accepts): calibration and [imu_noise]."""
    cfg: dict = {}
    if res["noise"]:
        rate = next(iter(res["noise"].values()))["allan"].tau0 ** -1
        cfg["imu_rate_hz"] = float(round(rate, 6))
    ud, rt, dr = res["updown"], res["rate_table"], res["drift"]
    if ud and len(ud["axes"]) == 3:
        cfg["accel_bias_cal_mps2"] = [ud["axes"][a]["bias_mps2"] for a in "xyz"]
        cfg["accel_scale_factor_cal"] = [ud["axes"][a]["scale_factor"] for a in "xyz"]
    if rt and len(rt["axes"]) == 3:
        cfg["gyro_scale_factor_cal"] = [rt["axes"][a]["scale_factor"] for a in "xyz"]
    if dr:
        cfg["gyro_bias_cal_rad_per_s"] = [dr[a]["bias_rad_per_s"] for a in "xyz"]
    elif rt and len(rt["axes"]) == 3:
        cfg["gyro_bias_cal_rad_per_s"] = [rt["axes"][a]["bias_rad_per_s"] for a in "xyz"]
    an = plan.analysis
    # The turn-on bias the filter starts from is uncertain by: the calibration's own uncertainty; the
    # wander of the bias over the lab day itself (rate random walk K over the day's span: the biases
    # measured early and late in the day differ by about this); and the day-to-day repeatability, which
    # one lab day cannot measure (from the plan; default: the default preset's values).
    rep_g = float(an.get("bias_repeatability_gyro_rad_per_s", DEFAULT_REPEATABILITY["gyro"]))
    rep_a = float(an.get("bias_repeatability_accel_mps2", DEFAULT_REPEATABILITY["accel"]))
    span = res.get("day_span_s", 0.0)

    def wander(prefix):
        if not res["noise"]:
            return 0.0
        k = max(res["noise"][f"{prefix}_{a}"]["fit"].value.get("K", 0.0) for a in "xyz"
                if f"{prefix}_{a}" in res["noise"])
        return k * math.sqrt(span)
    if dr:
        cal = max(dr[a]["bias_sigma_rad_per_s"] for a in "xyz")
        cfg["gyro_bias_residual_rad_per_s"] = math.sqrt(rep_g ** 2 + cal ** 2 + wander("gyro") ** 2)
    if ud and ud["axes"]:
        cal = max(v["bias_sigma_mps2"] for v in ud["axes"].values())
        cfg["accel_bias_residual_mps2"] = math.sqrt(rep_a ** 2 + cal ** 2 + wander("accel") ** 2)
    if res["noise"] and all(n in res["noise"] for n in AXES):
        def vec(prefix, term):
            return [float(res["noise"][f"{prefix}_{a}"]["fit"].value.get(term, 0.0)) for a in "xyz"]
        cfg["imu_noise"] = {"gyro_arw_rad_per_sqrt_s": vec("gyro", "N"),
                            "gyro_bias_instability_rad_per_s": vec("gyro", "B"),
                            "gyro_rrw_rad_per_s_sqrt_s": vec("gyro", "K"),
                            "accel_vrw_mps_per_sqrt_s": vec("accel", "N"),
                            "accel_bias_instability_mps2": vec("accel", "B"),
                            "accel_rrw_mps2_per_sqrt_s": vec("accel", "K"),
                            "bias_tau_s": float(an.get("bias_tau_s", 100.0))}
    return cfg


def preset_toml(cfg: dict) -> str:
    def val(v):
        return "[" + ", ".join(f"{x:.6e}" for x in v) + "]" if isinstance(v, list) else f"{v!r}"
    lines = ["# Filter parameters from `gpsins lab`: calibration (eq. 5.2, rate table, drift test) and the",
             "# Allan noise terms of the drift run. Use as a filter configuration (starts from preset 'default').", ""]
    lines += [f"{k} = {val(v)}" for k, v in cfg.items() if k != "imu_noise"]
    if "imu_noise" in cfg:
        lines += ["", "[imu_noise]"] + [f"{k} = {val(v)}" for k, v in cfg["imu_noise"].items()]
    return "\n".join(lines) + "\n"


def kalibr_yaml(res: dict) -> str | None:
    """Kalibr's imu.yaml: continuous-time densities, one value per sensor (RMS over the axes)."""
    n = res["noise"]
    if not n or not all(a in n for a in AXES):
        return None
    def rms(prefix, term):
        return math.sqrt(np.mean([n[f"{prefix}_{a}"]["fit"].value.get(term, 0.0) ** 2 for a in "xyz"]))
    rate = next(iter(n.values()))["allan"].tau0 ** -1
    return (f"# Kalibr IMU noise model from `gpsins lab` (drift run; RMS over x, y, z)\n"
            f"accelerometer_noise_density: {rms('accel', 'N'):.6e}   # m/s^2/sqrt(Hz)\n"
            f"accelerometer_random_walk: {rms('accel', 'K'):.6e}     # m/s^3/sqrt(Hz)\n"
            f"gyroscope_noise_density: {rms('gyro', 'N'):.6e}       # rad/s/sqrt(Hz)\n"
            f"gyroscope_random_walk: {rms('gyro', 'K'):.6e}         # rad/s^2/sqrt(Hz)\n"
            f"rostopic: /imu0\nupdate_rate: {rate:g}\n")


def to_json(res: dict) -> dict:
    """The result without arrays' bulk kept only where a reader needs them (Allan curves and bounds)."""
    out = {k: v for k, v in res.items() if k != "noise"}
    if res["noise"]:
        out["noise"] = {}
        for name, v in res["noise"].items():
            r, f = v["allan"], v["fit"]
            out["noise"][name] = {
                "estimator": r.estimator, "tau_s": r.tau.tolist(), "adev": r.adev.tolist(), "edf": r.edf.tolist(),
                "chi2_lo": r.lo.tolist(), "chi2_hi": r.hi.tolist(), "confidence": r.confidence,
                "eq59_rel_sigma": np.broadcast_to(r.rel_sigma_eq59, r.tau.shape).tolist(),
                "eq59_lo": r.eq59_lo.tolist(), "eq59_hi": r.eq59_hi.tolist(),
                "fit": f.value, "fit_sigma": f.sigma, "slope_readouts": f.slope_readouts,
                "gauss_markov_bump": v["bump"], "N_psd": v["N_psd"],
                "psd_averaged": {"f_hz": v["psd"][2].tolist(), "psd": v["psd"][3].tolist()}}
    return out


def run(plan_path: str | Path, out_dir: str | Path, figures: bool = True) -> dict:
    plan = load_plan(plan_path)
    res = run_plan(plan)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cfg = calibration_table(res, plan)
    res["filter_config"] = cfg
    (out / "imu_preset.toml").write_text(preset_toml(cfg), encoding="utf-8")
    y = kalibr_yaml(res)
    if y:
        (out / "imu.yaml").write_text(y, encoding="utf-8")
    (out / "lab.json").write_text(results.json_text(to_json(res), indent=1) + "\n", encoding="utf-8")
    from . import lab_report

    lab_report.write(res, out, figures=figures)
    return res


__all__ = ["load_plan", "run_plan", "run", "Plan", "PlanError", "RecordError"]
