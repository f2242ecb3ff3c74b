"""The lab's deterministic calibration (the FOI report, 5.1.2): up-down positions, the rate table and
the drift test, each with its uncertainty.
"""

from __future__ import annotations

import math

import numpy as np

from . import calibration, noise_fit, records
from .lab_plan import OMEGA_E, Plan, load, noise_value


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
        rec = load(plan, entry)
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
            m, s, n = _window_stats(rec.rates[a:b, 3 + i], rec.rate_hz, noise_value(noise, f"accel_{'xyz'[i]}"))
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
        value = noise_value(noise, f"accel_{a}")
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
        rec = load(plan, entry)
        warnings.extend(f"{rec.name}: {n}" for n in rec.notes)
        a = entry["axis"]
        i = "xyz".index(a)
        st = records.steady_windows(rec.rates, rec.rate_hz)
        if not st.windows:
            warnings.append(f"{rec.name}: no steady stretch (the table rate never settled): skipped")
            continue
        lo, hi = max(st.windows, key=lambda w: w[1] - w[0])
        w, w_sig = _table_rate(entry)
        m, s, n = _window_stats(rec.rates[lo:hi, i], rec.rate_hz, noise_value(noise, f"gyro_{a}"))
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
        value = noise_value(noise, f"gyro_{a}")
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
        m, s, n = _window_stats(rec.rates[a0:a1, i], rec.rate_hz, noise_value(noise, f"gyro_{a}"))
        sf = scale.get(a, 0.0)
        out[a] = {"bias_rad_per_s": m - (1 + sf) * w_b[i], "bias_sigma_rad_per_s": s, "mean_output_rad_per_s": m,
                  "earth_rate_rad_per_s": float(w_b[i]), "window_s": [a0 / rec.rate_hz, a1 / rec.rate_hz]}
    return out
