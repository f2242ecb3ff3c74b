"""The filter's statistics from the recording itself: per-source innovation consistency, and a
likelihood fit of the noise scales that makes it true.

A data set declares its sensors' noise from a datasheet or an Allan analysis, and its fixes their
formal sigmas. Both are often wrong on the vehicle: vibration, a warm-up, a gait or a mounting add
motion noise the bench never saw, and an RTK engine's sigmas are formal. A filter built on them is
over-confident, and its gate then refuses good fixes. ``fit_noise`` runs the filter over the
recording's own GNSS (outages already removed, so nothing scored is seen), the gate as the run has
it (``fit_start``), and scales four variances, each by a factor found by maximum likelihood of the
innovations (the sum over updates of NIS + ln det S, the Gaussian -2 log-likelihood up to a constant):

- the IMU's white noise, gyro and accelerometer apart (their process noise densities, the
  white part of the bias instability included);
- the fixes' position and velocity covariances (their stated sigmas, or the UERE and velocity sigma).

This is the innovation-based maximum-likelihood adaptive filter of Mehra (1970) reduced to a few
scale factors, solved offline by Nelder-Mead in the logarithms of the factors. ``SourceStats``
gives what the report shows per source: NIS/dof mean and median over every update (accepted or
not) and the lag-one autocorrelation of its normalised innovations.
"""

from __future__ import annotations

import math

import numpy as np

from . import runs as flt
from . import config as nav_config
from .inputs import ImuColumns

# Update kinds the fit scores (fix position 3D and 2D, fix velocity, the non-holonomic constraint).
FIT_KINDS = (1, 2, 3, 7)
# The factors are searched in ln space within these bounds (variance x 0.01 .. x 400).
LOG_SCALE_BOUNDS = (math.log(0.01), math.log(400.0))
SCALES = ("gyro_white", "accel_white", "fix_position", "fix_velocity", "fix_correlated")
# The fixes' correlated error is fitted as a variance on top of their white one: per north, east, down
# Gauss-Markov states with this correlation time (not fitted: two minutes of data cannot tell it), its
# variance the factor times the median stated variance (so the factor's search starts at "as large as
# the white part"); a declared model without it is the factor's lower bound.
FIX_CORRELATED_TAU_S = 30.0
MAX_EVALUATIONS = 80
# The fit's runs cover the recording from its start to this long after its first fix: each of the
# up to 81 evaluations is a whole filter run, so the simulated 43-minute 200 Hz car (5 Hz fixes) took
# 312 s to fit whole. On its first 600 s: 72 s (same load), the fixes' factors within 2 % of the
# whole recording's (position 0.768 / 0.774, velocity 1.17 / 1.19), the IMU's and the correlated
# error's less well determined either way (gyro 0.41 / 0.46, accelerometer 0.85 / 0.60, correlated
# 0.38 / 0.15). Every recording in tests/data/ is shorter, so none of them changes.
FIT_SPAN_S = 600.0


class SourceStats:
    """Per update kind, gathered chunk by chunk (``add``): count, NIS/dof mean and median over all
    updates, the share rejected or down-weighted, and the lag-one autocorrelation of the normalised
    innovations (each axis's innovation over its sigma, consecutive finite values of that kind, about
    their mean). Kept per update: its NIS/dof only (for the median), 8 bytes; the autocorrelation from
    running sums, so a 4-hour tight run (964 000 updates) holds 8 MB, not its 140 MB of update columns."""

    def __init__(self):
        self._kinds: dict[int, dict] = {}

    def add(self, updates: dict) -> "SourceStats":
        kind = np.asarray(updates["kind"])
        if not len(kind):
            return self
        nis, dof = np.asarray(updates["nis"]), np.asarray(updates["dof"]).astype(float)
        acc = np.asarray(updates["accepted"])
        scaled = np.asarray(updates.get("r_scale", np.ones(len(kind)))) > 1.0
        z = np.atleast_2d(np.asarray(updates["innovation"]) / np.asarray(updates["innovation_sigma"]))
        z = z.reshape(len(kind), -1)
        for k in np.unique(kind):
            sel = kind == k
            st = self._kinds.setdefault(int(k), {"n": 0, "per_dof": [], "rejected": 0, "downweighted": 0, "axes": {}})
            ok = sel & np.isfinite(nis) & (dof > 0)
            st["n"] += int(sel.sum())
            st["per_dof"].append(nis[ok] / dof[ok])
            st["rejected"] += int(np.sum(~acc[sel]))
            st["downweighted"] += int(np.sum(scaled[sel] & acc[sel]))
            for j, col in enumerate(z[sel].T):
                c = col[np.isfinite(col)]
                if not len(c):
                    continue
                ax = st["axes"].setdefault(j, {"n": 0, "s1": 0.0, "s2": 0.0, "s12": 0.0, "first": c[0], "last": None})
                if ax["last"] is not None:
                    ax["s12"] += float(ax["last"] * c[0])
                ax["n"] += len(c)
                ax["s1"] += float(np.sum(c))
                ax["s2"] += float(np.dot(c, c))
                ax["s12"] += float(np.dot(c[:-1], c[1:]))
                ax["last"] = c[-1]
        return self

    def result(self) -> dict:
        out = {}
        for k in sorted(self._kinds):
            st = self._kinds[k]
            per_dof = np.concatenate(st["per_dof"])
            out[flt.UPDATE_KINDS.get(k, str(k))] = {
                "n": st["n"],
                "nis_per_dof_mean": float(per_dof.mean()) if len(per_dof) else None,
                "nis_per_dof_median": float(np.median(per_dof)) if len(per_dof) else None,
                "rejected_fraction": st["rejected"] / st["n"],
                "downweighted": st["downweighted"],
                "lag1_autocorrelation": _lag1(st["axes"].values()),
            }
        return out


def _lag1(axes) -> float | None:
    """The mean over axes of sum (x_t - m)(x_t+1 - m) / sum (x_t - m)^2 from an axis's running sums."""
    vals = []
    for a in axes:
        n = a["n"]
        if n < 3:
            continue
        m = a["s1"] / n
        den = a["s2"] - n * m * m
        num = a["s12"] - m * (2.0 * a["s1"] - a["first"] - a["last"]) + (n - 1) * m * m
        if den > 0:
            vals.append(num / den)
    return float(np.mean(vals)) if vals else None


def summary_lines(run: dict) -> list[str]:
    """What a run's summary (run.json) says of its statistics, a line each: per aiding source NIS/dof mean
    and median over all its updates, the lag-one autocorrelation of its normalised innovations (about 0
    when the model's noise is white and right), rejected and down-weighted; what was fitted."""
    out = []
    for name, s in (run.get("sources") or {}).items():
        if s.get("nis_per_dof_mean") is None:
            continue
        rho = s.get("lag1_autocorrelation")
        out.append(f"{name}: {s['n']} updates, NIS/dof mean {s['nis_per_dof_mean']:.2f} median "
                   f"{s['nis_per_dof_median']:.2f}, lag-one autocorrelation "
                   f"{'-' if rho is None else f'{rho:.2f}'}, {100 * s['rejected_fraction']:.1f} % rejected, "
                   f"{s['downweighted']} down-weighted")
    fit = run.get("noise_fit") or {}
    if fit.get("factors"):
        out.append("noise fitted from the recording (variance x): "
                   + ", ".join(f"{k} {v:.2f}" for k, v in fit["factors"].items()))
    m = run.get("mounting_fit")
    if m:
        out.append(f"mounting estimated: body to vehicle yaw {m['yaw_deg']:.2f} deg, pitch {m['pitch_deg']:.2f} deg "
                   f"over {m['epochs']} epochs"
                   + (f" (velocity direction {m['direction_yaw_deg']:.2f} / {m['direction_pitch_deg']:.2f} deg, "
                      f"refined by likelihood in {m['refine_evaluations']} runs)" if "refine_evaluations" in m else ""))
    arm = run.get("lever_arm_fit")
    if arm:
        out.append("antenna lever arm from the recording: [" + ", ".join(f"{x:.3f}" for x in arm["lever_arm_body_m"])
                   + "] m body axes (stated [" + ", ".join(f"{x:.3f}" for x in arm["stated_m"]) + "] +- "
                   + "/".join(f"{x:.3f}" for x in arm["sigma_m"]) + f" m, {arm['evaluations']} runs)")
    c = run.get("constraint_fit")
    if c:
        out.append(f"vehicle constraint from the recording: every {c['interval_s']:.2f} s, sigma lateral "
                   f"{c['lateral_sigma_mps']:.3f} m/s, vertical {c['vertical_sigma_mps']:.3f} m/s")
    return out


def minus_two_log_likelihood(updates: dict) -> float:
    """-2 ln L of a run's fix and constraint innovations (FIT_KINDS), up to a constant."""
    kind = np.asarray(updates["kind"])
    sel = np.isin(kind, FIT_KINDS)
    nis = np.asarray(updates["nis"])[sel]
    logdet = np.asarray(updates["log_det_s"])[sel]
    ok = np.isfinite(nis) & np.isfinite(logdet)
    if not ok.any():
        return math.inf
    # Updates the run could not form (a guarded covariance) count as very unlikely, so that a
    # scale that breaks the filter is never chosen.
    return float(np.sum(nis[ok] + logdet[ok]) + 1e3 * np.sum(~ok))


def scaled(cfg: dict, fixes: np.ndarray, factors: dict) -> tuple[dict, np.ndarray]:
    """The configuration and fix table with the variances scaled by ``factors`` (names as SCALES)."""
    core = nav_config.core_config(cfg)
    g, a = math.sqrt(factors.get("gyro_white", 1.0)), math.sqrt(factors.get("accel_white", 1.0))
    p, v = math.sqrt(factors.get("fix_position", 1.0)), math.sqrt(factors.get("fix_velocity", 1.0))
    out = dict(cfg)
    out.update(gyro_arw_rad_per_sqrt_s=(np.asarray(core.gyro_arw_rad_per_sqrt_s) * g).tolist(),
               gyro_flicker_white_rad_per_sqrt_s=(np.asarray(core.gyro_flicker_white_rad_per_sqrt_s) * g).tolist(),
               accel_vrw_mps_per_sqrt_s=(np.asarray(core.accel_vrw_mps_per_sqrt_s) * a).tolist(),
               accel_flicker_white_mps_per_sqrt_s=(np.asarray(core.accel_flicker_white_mps_per_sqrt_s) * a).tolist(),
               fix_uere_m=float(core.fix_uere_m) * p, fix_uere_2d_m=float(core.fix_uere_2d_m) * p,
               fix_velocity_sigma_mps=float(core.fix_velocity_sigma_mps) * v)
    f = np.array(fixes, float, copy=True)
    stated = None
    if f.shape[1] >= 16:
        stated = np.nanmedian(np.where(f[:, 10:13] > 0, f[:, 10:13], np.nan), axis=0)
        f[:, 10:13] *= p
        f[:, 13:16] *= v
    c_factor = factors.get("fix_correlated")
    if c_factor is not None:
        white = stated if stated is not None and np.isfinite(stated).all() else \
            float(core.fix_uere_m) * np.nanmedian(f[:, 7:9], axis=0)[[0, 0, 1]]
        out.update(fix_error_gm_sigma_m=(np.sqrt(c_factor) * np.asarray(white)).tolist(),
                   fix_error_gm_tau_s=FIX_CORRELATED_TAU_S, fix_error_gm_dop_scaled=False,
                   fix_error_fast_sigma_m=[0.0, 0.0, 0.0])
    return out, f


def fit_window(imu, fixes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The IMU samples (a table, or ImuColumns) and fixes the fit runs over: up to FIT_SPAN_S after the
    first fix, the samples as the (n, 7) table of those rows only."""
    times = imu.t if isinstance(imu, ImuColumns) else np.asarray(imu)[:, 0]
    end = fixes[0, 0] + FIT_SPAN_S if len(fixes) else np.inf
    rows = int(np.searchsorted(times, end, side="right"))  # the decoders' times increase
    return np.asarray(imu[:rows], dtype=float), fixes[fixes[:, 0] <= end]


def fit_start(imu, fixes: np.ndarray, cfg: dict) -> tuple[np.ndarray, np.ndarray, dict]:
    """What a likelihood fit's runs share: the samples and fixes of ``fit_window``, and the configuration
    with the GNSS reset off (a hypothesis that loses the fixes pays for it in full), started at the heading
    the declared model's run found, so that a heading search is done once.

    Every update is scored, and only the standstill updates are gated (``gate_standstill_only``, when the
    run has a gate). The gate is what ends a standstill the detector began too early or left too late: a
    refused zero-velocity update. With no gate at all, a car pulling away smoothly inside a gap in the
    fixes kept its velocity pinned at zero, and the first fixes after the gap missed by 2.6 m against a
    predicted sigma of 3 cm (simulated car, seed 1: 8 fixes, 69 % of the fixes' NIS); the likelihood then
    preferred any variance that hid them: the gyro's at 100-2000 x, the simulator's own noise declared
    exactly, which left the drift at 3.4 m instead of 0.8 m. With the fixes gated too, a hypothesis whose
    gate refused a few fixes lost them from its trajectory, and the fit moved away from it for that:
    on the 800 s mismatched car (bench_car_outages.py, seed 0) the accelerometer's factor went to x 16.8
    against x 2.2 ungated (the truth x 9)."""
    imu, fixes = fit_window(imu, fixes)
    base = dict(cfg, gnss_reset_timeout_s=0.0)
    if cfg.get("gate_probability", 0.0) > 0.0:
        base["gate_standstill_only"] = True
    if flt.needs_heading_search(base):
        found = flt.search_heading(imu, fixes, base)
        if found["yaw_deg"] is not None:
            base = flt.starting_at_yaw(base, found["yaw_deg"], found["sigma_deg"])
    return imu, fixes, base


def run_likelihood(imu: np.ndarray, fixes: np.ndarray, cfg: dict, mode: str = "loose") -> float:
    """-2 ln L of one run over ``fixes`` with ``cfg`` (no epochs kept: only its updates are read)."""
    return minus_two_log_likelihood(flt.run(imu, fixes, cfg, mode=mode, output_every=10 ** 9).updates)


def minimise_from(cost, x0: np.ndarray, steps: np.ndarray, *, max_evaluations: int, tolerance: float) -> dict:
    """Nelder-Mead on ``cost`` from ``x0`` (first simplex x0 + each of ``steps``), keeping ``x0`` unless the
    search beats it: ``{"x", "at_start", "best", "evaluations"}``. The fits of a few of the filter's inputs to
    the recording (the lever arm, the mounting) each run one filter pass per evaluation."""
    from scipy.optimize import minimize

    count = [0]

    def counted(x: np.ndarray) -> float:
        count[0] += 1
        return cost(x)

    at_start = counted(x0)
    res = minimize(counted, x0, method="Nelder-Mead",
                   options={"maxfev": max_evaluations, "xatol": tolerance, "fatol": 0.5,
                            "initial_simplex": np.vstack([x0, x0 + np.diag(steps)])})
    better = res.fun < at_start
    return {"x": res.x if better else x0, "at_start": at_start, "best": float(min(res.fun, at_start)),
            "evaluations": count[0]}


def fit_noise(imu, fixes: np.ndarray, cfg: dict, *, mode: str = "loose", scales=SCALES) -> dict:
    """Fit the four variance factors (SCALES) by likelihood over the fixes given (the first
    FIT_SPAN_S of them, ``fit_window``); returns
    ``{"factors": {...}, "minus_two_log_likelihood": {"declared", "fitted"}, "evaluations", "fixes", "span_s"}``.
    The runs start as ``fit_start`` sets them up."""
    from scipy.optimize import minimize

    imu, fixes, base = fit_start(imu, fixes, cfg)
    cache: dict[tuple, float] = {}

    def likelihood(factors: dict) -> float:
        c, f = scaled(base, fixes, factors)
        return run_likelihood(imu, f, c, mode)

    def cost(x: np.ndarray) -> float:
        key = tuple(np.round(x, 6))
        if key not in cache:
            cache[key] = likelihood(dict(zip(scales, np.exp(np.clip(x, *LOG_SCALE_BOUNDS)))))
        return cache[key]

    declared = likelihood({})
    x0 = np.zeros(len(scales))
    res = minimize(cost, x0, method="Nelder-Mead", bounds=[LOG_SCALE_BOUNDS] * len(scales),
                   options={"maxfev": MAX_EVALUATIONS, "xatol": 0.05, "fatol": 0.5,
                            "initial_simplex": np.vstack([x0, np.eye(len(scales)) * 1.5])})
    factors = {k: float(v) for k, v in zip(scales, np.exp(res.x))} if res.fun < declared else {}
    return {"factors": factors,
            "minus_two_log_likelihood": {"declared": declared, "fitted": float(min(res.fun, declared))},
            "evaluations": len(cache) + 1, "fixes": int(len(fixes)),
            "span_s": float(fixes[-1, 0] - fixes[0, 0]) if len(fixes) else 0.0}

