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
from pathlib import Path

import numpy as np

from ..replay import results
from . import noise_fit, records
from .records import AXES, RecordError
from .lab_plan import DEFAULT_REPEATABILITY, Plan, PlanError, load, load_plan, noise_analysis
from .lab_calibration import drift_test, rate_table, updown


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
        drift_rec = load(plan, plan.drift)
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
                                f"of freedom reach only {usable:.0f} s, so bias instability and rate random walk "
                                f"rest on few points (the report used 50 min; hours are better)")
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
