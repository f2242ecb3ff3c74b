"""Replay a logger session or a data set through the filter.

session directory -> decoded measurements -> time alignment -> filter -> results directory;
data-set TOML (``gpsins.dataset``) -> decoded files -> filter -> the same results directory:

- ``solution.parquet`` (per epoch), ``updates.parquet`` (per update), ``results.npz`` (the
  receiver's fixes, outages, scoring) and with ``--smooth`` ``smoothed.parquet``: the arrays of
  ``RESULT_ARRAYS``, written chunk by chunk as the filter runs so that memory does not grow with
  the session (``results`` says why Parquet, ``results.load`` reads them all back);
- ``solution.pos``: RTKLIB-style positions (GPST, latitude, longitude, height,
  standard deviations), for RTKLIB's plot tools and comparisons;
- ``config.toml``: the exact filter configuration used;
- ``run.json``: counters, what was skipped and why, the alignment's summary,
  timings and summary statistics; with a reference (``--reference``, a data set's
  ``[scoring]``, or a session's simulated truth) the errors against it and, with
  ``--outages``, the per-outage drift (``outages.Score.summary``).

The filter runs in chunks of IMU samples (``filter.ChunkedRun``); each chunk's epochs go through
``solution.Stream`` (derived columns, truth errors, .pos lines, running statistics) and are
dropped. ``--mode both`` decodes and aligns the session once for both filters (``load_inputs``,
then ``run_mode`` per mode).

What a data set gives the filter (each only where neither the data set's ``[filter]``
table nor ``--set`` names the key itself): ``lever_arm_body_m`` from ``[gnss] antenna_m``;
``imu_rate_hz`` from the median IMU interval (the core's gap bridging and standstill
window use it); ``imu_increments_cover_gaps`` for IMU rates (their increments cover every step); ``use_fix_velocity`` when the fixes carry velocities and
``fix_velocity_sigma_mps`` from their stated sigmas (``dataset.velocity_sigma``, for fixes that
state none); ``fix_velocity_lag_s`` from ``[gnss] velocity_lag_s`` (``"measured"``: ``dataset.velocity_lag``,
which run.json reports for any data set whose fixes allow it); ``pseudorange_decimation`` so that the tight
filter uses about one epoch per second whatever the receiver's rate. Fix position and velocity
sigmas travel per fix in the fix table's sigma columns (``dataset.fix_table``). The mounting rotation and
the IMU time offset are applied by ``dataset.load``.

Modes: ``loose`` (fixes), ``tight`` (pseudoranges; fixes only start the filter and give
the heading) and ``ins``: free inertial navigation after the initialisation. ``ins`` is
the loose filter fed the fixes only up to the one at which the heading became known
(levelling, position and heading done), with zero-velocity and zero-rate updates off
for the whole run; everything after that fix is the IMU alone. Its drift is scored over
that whole free stretch as one outage.

Outages (``--outages``): every fix and pseudorange whose time falls in an outage is
removed before the filter sees anything.
"""

from __future__ import annotations

import errno
import hashlib
import json
import shlex
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..dataset import load as dataset_mod
from ..dataset import fixes as dataset_fixes
from .. import evaluate
from ..nav import runs as flt
from ..session import measurements
from ..formats import gpstime
from ..session import layouts
from ..evaluate import outages as outages_mod
from ..nav import inputs as nav_inputs
from ..nav import config as nav_config
from ..dataset import doctor
from ..nav import estimator as estimator_mod, mounting, noise_from_data
from ..session import measurements_ubx
from ..formats import reference as reference_mod
from . import results, solution
from ..timing import alignment
from .. import __version__
from ..formats import rinex

DEFAULT_GPS_LATENCY_S = 0.0205  # receiver's epoch-to-first-byte delay (assumed 20 ms) + the logger's
DEFAULT_IMU_LATENCY_S = 0.0005

RESULT_ARRAYS = {
    "t": "GPS time, s since the start of `week`", "week": "GPS week of t = 0",
    "r_ecef": "position, m", "v_ecef": "velocity, m/s", "q_eb": "attitude body->ECEF (w, x, y, z)",
    "llh": "latitude, longitude (rad), height (m)", "ypr_deg": "yaw, pitch, roll relative to NED, deg",
    "gyro_bias": "rad/s", "accel_bias": "m/s^2", "sigma": "error-state standard deviations",
    "sigma_ned_m": "position sigma north, east, down", "sigma_ypr_deg": "attitude sigma about N, E, D axes",
    "standstill": "standstill detected", "heading_known": "heading initialised",
    "fixes": "receiver fixes [t, r xyz, v xyz, hdop, vdop, mode] (data sets: then sigma n e d, vn ve vd)",
    "fix_sats": "satellites used per fix",
    "upd_*": "updates: t, kind, id, dof, nis, gate, log_det_s, r_scale (> 1: used down-weighted), accepted, "
             "innovation (3), innovation_sigma (3)",
    "err_ned_m": "position error (estimate - truth) NED", "err_ypr_deg": "attitude error",
    "err_v_ned_mps": "velocity error NED", "nees9": "NEES of the 9 navigation states",
    "seg_labels": "truth segment labels", "seg_t": "truth segments' start and end times",
    "sigma_v_ned_mps": "velocity sigma north, east, down",
    "clock": "tight mode: receiver clock bias (m) and drift (m/s); their sigmas are the last two of `sigma` "
             "(before the time offset's with estimate_time_offset)",
    "time_offset_s": "with estimate_time_offset: the IMU time offset state dt_imu (s), to add to the data set's "
                     "[imu] time_offset_s; its sigma is the last of `sigma`",
    "fix_error": "loose mode with fix_error_gm_sigma_m: the fixes' correlated error state (ECEF; m, or m per unit of DOP with fix_error_gm_dop_scaled); sigmas last of `sigma` (before the time offset's)",
    "r_point_ecef": "position of the scored point (antenna unless --point imu; a session's truth: IMU), m",
    "lever_arm_body_m": "antenna relative to the IMU, body axes (the configuration's lever arm)",
    "outages": "outage schedule [start, end), same time base as t",
    "ref_t": "reference epochs used for scoring", "ref_r_ecef": "reference positions",
    "ref_err_ned_m": "solution minus reference at ref_t, NED", "ref_outage": "outage index of each ref_t (-1 outside)",
    "drift_t_s": "time since the outage began, per reference epoch inside one", "drift_h_m": "horizontal drift",
    "drift_v_m": "vertical drift", "drift_outage": "outage index of each drift row",
}
MODES = ("loose", "tight", "ins")
UNKNOWN_CN0_DBHZ = 99.0  # what the tight filter is given for a pseudorange whose C/N0 the file does not state
# An outside receiver's oscillator unless its data set says otherwise: a free-running TCXO, whose frequency
# random walk (h_-2 = 2e-20) drives the clock drift by sqrt(2 pi^2 h_-2) c = 0.19 m/s per sqrt(s). The
# preset's 0.01 is the simulated receiver's steered clock; the walk's u-blox drift moves by 0.37 m/s within
# 1 s and ramps 15 m/s over its 134 s, which 0.01 cannot follow once Doppler pins the drift (the tight walk's
# vertical error went to 17 m).
REAL_RECEIVER_CLOCK_DRIFT_NOISE_MPS_PER_SQRT_S = 0.19
POINTS = ("antenna", "imu")
TRUTH_SCORING_HZ = 10.0  # a simulated truth scored as the reference is taken at about this rate
POS_TIME_RESOLUTION_S = 0.001  # an RTKLIB .pos reference's epochs are printed to the millisecond


@dataclass
class ReplayResult:
    out: Path
    mode: str
    summary: dict
    stretches: list = field(default_factory=list)  # a restarted receiver's session: every stretch's result


def load_session_truth(directory: Path, t_offset: float) -> tuple[evaluate.Truth, dict] | None:
    """The simulated truth next to a session (session dir or its parent), on the replay's time base."""
    for p in (directory / "truth.npz", directory.parent / "truth.npz"):
        if p.exists():
            from ..formats.truth import open_truth  # memory-mapped: a day-long truth is not read whole

            z = open_truth(p)
            tow = z["tow_s"] + (int(z["gps_week"]) * 604800.0) - t_offset
            evaluate.release_pages(z["tow_s"])
            model = json.loads(str(z["model_json"])) if "model_json" in z else {}
            extra = {"seg_labels": z["segment_labels"], "seg_t": z["segment_t"] + float(z["t0_tow_s"]) +
                     int(z["gps_week"]) * 604800.0 - t_offset,
                     "simulation": {"scenario": model.get("scenario"), "seed": model.get("seed"), "truth": str(p)}}
            return evaluate.Truth(tow, z["r_ecef"], z["v_ecef"], z["q_eb"]), extra
    return None


@dataclass
class Inputs:
    """What a replay feeds the filter, on one time base: GPS seconds since the start of ``week``."""

    source: Path
    kind: str  # "session" | "dataset"
    week: int
    imu: "flt.ImuColumns | np.ndarray"  # (n, 7) rows [t, dtheta xyz, dv xyz]
    fixes: np.ndarray  # (m, 10) every fix the receiver (or file) gave
    fix_sats: np.ndarray  # (m,)
    gnss_span: tuple[float, float]  # first and last GNSS epoch: the outage schedule's origin
    pseudoranges: np.ndarray | None = None  # (k, 5), or (k, 6) with the Doppler: tight
    ephemerides: list = field(default_factory=list)
    klobuchar: tuple | None = None
    base_config: object = None  # load_config's source
    explicit_keys: set = field(default_factory=set)  # keys the user gave: data-derived values do not replace them
    data_config: dict = field(default_factory=dict)  # configuration derived from the data
    truth: tuple | None = None  # (evaluate.Truth, extra arrays) of a simulated session
    reference: tuple | None = None  # (t, r_ecef, name) at the antenna point
    outage_spec: outages_mod.OutageSpec | None = None  # a data set's [scoring] outages
    info: dict = field(default_factory=dict)  # run.json entries


def is_dataset(source: str | Path) -> bool:
    """A data-set file (TOML) rather than a session directory."""
    p = Path(source)
    return p.suffix.lower() == ".toml" and not p.is_dir()


def _decode_stretches(session: Path, config, overrides: dict) -> list:
    if measurements_ubx.is_ublox(session):  # a u-blox receiver: NAV-PVT fixes carry its own accuracy
        return [measurements_ubx.decode_session(session, nav_config.value(nav_config.load_config(config, overrides or {}),
                                                                   "fix_uere_m"))]
    return measurements.decode_stretches(session)


def _session_inputs(session: Path, mode: str, config, timing_method: str, gps_latency_s: float,
                    imu_latency_s: float, truth: bool, nav, overrides: dict, dec, decode_s: float) -> Inputs:
    """``dec``: the session (or one stretch of it), decoded in ``decode_s``."""
    t0 = time.perf_counter()
    # A BP3010's increments stay counts of its units while the session is replayed (exact; 200 MB less a day).
    increments = dec.imu.dtheta, dec.imu.dv, dec.imu.lsb
    dec.imu.dtheta = dec.imu.dv = None
    decode_s += time.perf_counter() - t0
    t1 = time.perf_counter()
    al = alignment.align(dec.gps.tow, dec.gps.stamps, dec.gps.week, dec.imu.stamps, dec.imu.counter, dec.imu.rate_hz,
                      method=timing_method, gps_latency_s=gps_latency_s, imu_latency_s=imu_latency_s)
    align_s = time.perf_counter() - t1
    imu = nav_inputs.ImuColumns(al.imu_t, *increments)
    fixes = dec.gps.fixes
    span = (float(fixes[0, 0]), float(fixes[-1, 0])) if len(fixes) else (float(imu[0, 0]), float(imu[-1, 0]))
    inp = Inputs(session, "session", int(dec.gps.week), imu, fixes, dec.gps.fix_sats, span, base_config=config)
    if mode == "tight":
        klob = None
        if dec.gps.iono is not None:
            klob = (dec.gps.iono.alpha, dec.gps.iono.beta)
        elif nav is not None:
            n = rinex.read_nav(nav)
            klob = (n.alpha, n.beta) if n.alpha else None
        ephs = dec.gps.decoded_ephemerides(dec.skipped)
        if nav is not None:
            ephs += rinex.read_nav(nav).ephemerides
        # By columns in exact smaller types (a day's float table is 200 MB); a Superstar session's are already.
        prs = dec.gps.pseudoranges
        inp.pseudoranges = prs if isinstance(prs, nav_inputs.PseudorangeColumns) else nav_inputs.PseudorangeColumns.compact(prs)
        dec.gps.pseudoranges = None
        inp.ephemerides, inp.klobuchar = ephs, klob
    inp.truth = load_session_truth(session, dec.gps.week * gpstime.SECONDS_PER_WEEK) if truth else None
    max_gap = float(nav_config.load_config(config, overrides).get("max_gap_s", 0.5))
    inp.info = {"session": str(session), "alignment": al.summary(), "decode_s": decode_s, "align_s": align_s,
                "imu_gaps_longer_than_max_gap": al.gap_list(min_s=max_gap) if timing_method == "robust" else [],
                "warnings": al.warnings if timing_method == "robust" else [], "skipped": dict(dec.skipped)}
    return inp


def _spp_fixes(pr, nav, t0: float) -> tuple[np.ndarray, np.ndarray]:
    """Single-point fixes from pseudoranges (a RINEX data set has no receiver fixes): they start the tight
    filter and aid the loose one; hdop/vdop are the solution's DOPs."""
    from .. import _core
    store = nav.store()
    pr = pr.select(pr.prn <= 32)  # the single-point solver has one clock: GPS's
    rows, sats = [], []
    guess = np.zeros(3)
    for t, prns, prs in pr.epochs():
        r = _core.gnss.spp(store, t, prns, prs, nav.alpha, nav.beta, 10.0, True, True, True, True, guess)
        if r["ok"]:
            guess = r["r_ecef"]
            rows.append([t - t0, *r["r_ecef"], np.nan, np.nan, np.nan, r["hdop"], r["vdop"], 2.0])
            sats.append(r["n_used"])
    return np.array(rows, float).reshape(-1, 10), np.array(sats, int)


def _dataset_inputs(path: Path, config, overrides: dict, modes=("loose",), force: bool = False) -> Inputs:
    t0 = time.perf_counter()
    ds = dataset_mod.load(path)
    decode_s = time.perf_counter() - t0
    diagnosis = doctor.diagnose(ds, modes)
    if diagnosis.errors() and not force:
        raise dataset_mod.DatasetError(path, "the data contradict the declaration:\n  " + "\n  ".join(
            f.line() for f in diagnosis.errors()) + "\n(`gpsins check` shows every check; --force replays anyway)")
    first, last = ds.gnss_span()
    week = int(min(first, ds.imu.t_abs[0]) // gpstime.SECONDS_PER_WEEK)
    t_week = week * gpstime.SECONDS_PER_WEEK
    imu = nav_inputs.ImuColumns(ds.imu.t_abs - t_week, ds.imu.dtheta_rad, ds.imu.dv_mps)
    explicit = set(ds.filter_table) if config is None else set(_config_keys(config))
    explicit |= set(overrides)
    base = config if config is not None else (dict(ds.filter_table) or None)
    cfg0 = nav_config.load_config(base, overrides)
    # The data's own statistics: a generic MEMS unit's priors, the noise fitted to the recording.
    derived: dict = {"lever_arm_body_m": ds.antenna_m.tolist(), **dataset_mod.GENERIC_MEMS}
    dt = np.diff(imu.t)
    dt = dt[dt > 0]
    if len(dt):
        derived["imu_rate_hz"] = float(1.0 / np.median(dt))
    if ds.imu.covers_gaps:
        derived["imu_increments_cover_gaps"] = True
    uere = float(nav_config.value(cfg0, "fix_uere_m"))
    measured_lag = None
    if ds.fixes is not None and len(ds.fixes):
        fixes = dataset_fixes.fix_table(ds.fixes, t_week, uere, ds.sigma_floor_m, ds.sigma_default_m,
                                      ds.velocity_sigma_floor_mps)
        sats = ds.fixes.ns.astype(int)
        if np.mean(np.isin(ds.fixes.q, dataset_mod.CARRIER_QUALITIES)) >= 0.5:
            derived.update(dataset_mod.STANDALONE_FIX_MODEL_OFF)
        vs = dataset_fixes.velocity_sigma(ds.fixes, ds.velocity_sigma_floor_mps)
        if vs is not None:
            # Per-fix velocity sigmas travel in the fix table; this median only stands in where a fix has none.
            derived.update(use_fix_velocity=True, fix_velocity_sigma_mps=vs, fix_velocity_sigma_hdop_scaled=False)
            measured_lag = dataset_fixes.velocity_lag(ds.fixes)
            if ds.velocity_lag_s == "measured":
                if measured_lag is None:
                    ds.notes.append('[gnss] velocity_lag_s = "measured": too few RTK-fixed epochs to measure it; '
                                    "0 used")
                derived["fix_velocity_lag_s"] = max(0.0, measured_lag["lag_s"]) if measured_lag else 0.0
            elif ds.velocity_lag_s > 0.0:
                derived["fix_velocity_lag_s"] = ds.velocity_lag_s
    elif ds.pseudoranges is not None:
        fixes, sats = _spp_fixes(ds.pseudoranges, ds.navigation, t_week)
    else:
        fixes, sats = np.zeros((0, 10)), np.zeros(0, int)
    inp = Inputs(path, "dataset", week, imu, fixes, sats, (first - t_week, last - t_week), base_config=base,
                 explicit_keys=explicit, outage_spec=ds.outages)
    if ds.pseudoranges is not None and len(ds.pseudoranges):
        inp.pseudoranges = ds.pseudoranges.table(t_week)
        # C/N0 unknown (RINEX without S1): not a weak signal, so not masked by pseudorange_min_cn0_dbhz.
        inp.pseudoranges[~np.isfinite(ds.pseudoranges.cn0_dbhz), 3] = UNKNOWN_CN0_DBHZ
        inp.ephemerides = list(ds.navigation.ephemerides)
        inp.klobuchar = (ds.navigation.alpha, ds.navigation.beta) if len(ds.navigation.alpha) == 4 else None
        if ds.ionosphere == "dual-frequency":  # the ranges come without their delay
            inp.klobuchar = None
            derived["pseudorange_ionosphere"] = False
        ep = np.unique(ds.pseudoranges.t_abs)
        if len(ep) > 1:
            rate = 1.0 / float(np.median(np.diff(ep)))
            derived["pseudorange_decimation"] = max(1, int(round(rate)))  # about one epoch per second
        derived["clock_drift_noise_mps_per_sqrt_s"] = REAL_RECEIVER_CLOCK_DRIFT_NOISE_MPS_PER_SQRT_S
    # A car's body axes are its vehicle axes (dataset spec): its heading is its course, and it takes the
    # non-holonomic constraint; anything else may point away from where it goes (handheld).
    derived["platform"] = "vehicle" if ds.vehicle_kind == "car" else "handheld"
    if ds.vehicle_kind == "car":
        derived["nonholonomic_constraint"] = True
        # The mounting's fine misalignment, unless the data set states it (mounting.py).
        derived["estimate_mounting"] = not any(k.startswith("body_to_vehicle_ypr") for k in explicit)
        # The noise from the recording (noise_from_data). Not for a hand-carried device: its gait is motion
        # the error model has no term for, and a white-noise fit takes it for IMU noise (the walk: gyro and
        # accelerometer variance x 100-400, drift RMS 2.36 -> 4.66 m), as the gate took it for outliers.
        derived["fit_noise"] = True
    inp.data_config = {k: v for k, v in derived.items() if k not in explicit}
    if ds.reference is not None:
        inp.reference = (ds.reference.t_abs - t_week, ds.reference.r_ecef, ds.reference.source)
    n_fix_q = {dataset_fixes.Q_NAMES.get(int(q), str(q)): int(n) for q, n in
               zip(*np.unique(ds.fixes.q, return_counts=True))} if ds.fixes is not None else {}
    inp.info = {"dataset": str(path), "name": ds.name, "decode_s": decode_s, "skipped": dict(ds.skipped),
                "warnings": list(ds.notes), "imu_to_body": ds.imu_to_body.tolist(),
                "imu_time_offset_s": ds.imu_time_offset_s, "imu_alignment": ds.imu.alignment,
                "antenna_m": ds.antenna_m.tolist(),
                "gnss_format": ds.gnss_format, "ionosphere": ds.ionosphere, "vehicle_kind": ds.vehicle_kind,
                "fix_quality": n_fix_q,
                "from_data": inp.data_config, "velocity_lag_measured": measured_lag,
                "ephemerides_prn": ds.navigation.prns() if ds.navigation is not None else [],
                "doctor": diagnosis.as_dict()}
    inp.info["warnings"] += [f.line() for f in diagnosis.findings if f.level in ("warning", "error")]
    return inp


def _with_estimated_mounting(imu, fixes: np.ndarray, cfg: dict) -> tuple[dict, dict | None]:
    """The car's body-to-vehicle yaw and pitch from a first pass without the non-holonomic constraint
    (``mounting.estimate``), put into the configuration; unchanged when the drive cannot show them."""
    step = max(1, int(round(float(cfg.get("imu_rate_hz", 100.0)) / 10.0)))  # 10 Hz is plenty for a median
    first = flt.run(imu, fixes, {**cfg, "nonholonomic_constraint": False}, mode="loose", output_every=step)
    found = mounting.estimate(first.t, first.q_eb, first.v_ecef, first.heading_known)
    if found is None:
        return cfg, None
    out = {k: v for k, v in cfg.items() if k not in ("body_to_vehicle_ypr_rad", "body_to_vehicle_ypr_deg")}
    out["body_to_vehicle_ypr_deg"] = [found["yaw_deg"], found["pitch_deg"], 0.0]
    return out, found


# A source whose updates are refused more often than this is worth a line on the terminal.
REJECTED_SHARE_WARNING = 0.05


def health_lines(counters: dict, sources: dict) -> list[str]:
    """One line for each way the run went wrong: diverged, GNSS resets, a source refused often."""
    lines = []
    if counters.get("diverged"):
        lines.append("the filter diverged (sustained GNSS rejection or an invalid covariance)")
    if counters.get("gnss_resets"):
        lines.append(f"{counters['gnss_resets']} GNSS reset(s): position and velocity were taken from GNSS")
    for name, s in sources.items():
        if s["rejected_fraction"] > REJECTED_SHARE_WARNING:
            lines.append(f"{name}: {100 * s['rejected_fraction']:.1f} % of {s['n']} updates rejected")
    return lines


def _config_keys(config) -> list[str]:
    """The keys a --config source names itself (a preset names none)."""
    if isinstance(config, dict):
        return list(config)
    if str(config) in nav_config.PRESETS and not Path(str(config)).suffix:
        return []
    import tomllib
    try:
        data = tomllib.loads(Path(config).read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError):
        return []  # load_config reports it
    return list(data.get("filter", data))


def _score_reference_system(ref, week: int, rows: dict) -> dict:
    """Errors against the session's own reference system (RTK position and dual-antenna heading
    and pitch, ``reference.csv`` beside the session), as a real campaign scores without truth;
    ``rows``: the solution rows that bracket its epochs (``solution.Brackets``)."""
    if ref is None or len(rows.get("t", ())) < 2:
        return {}
    summary = reference_mod.compare_summary(ref, week * gpstime.SECONDS_PER_WEEK + rows["t"], rows["r_imu"],
                                            rows["yaw"], rows["pitch"])
    return {"file": reference_mod.FILE_NAME, "damaged_lines": len(ref.damaged_lines), **summary}


HEADING_AIDING_INTERVAL_S = 1.0  # the reference's heading errors are partly slow (multipath): not at its full rate


def heading_aiding(ref, week: int, interval_s: float = HEADING_AIDING_INTERVAL_S) -> np.ndarray:
    """A reference system's dual-antenna heading and pitch as the filter's attitude input
    [t, yaw, pitch, sigma yaw, sigma pitch], at most one epoch per ``interval_s``."""
    ok = np.isfinite(ref.heading_rad) & np.isfinite(ref.sigma_heading_rad)
    t = ref.gps_seconds()[ok] - week * gpstime.SECONDS_PER_WEEK
    keep = np.ones(len(t), bool)
    last = -np.inf
    for i, x in enumerate(t):  # thin to the interval without drifting off it
        keep[i] = x - last >= interval_s - 1e-6
        last = x if keep[i] else last
    pitch_ok = np.isfinite(ref.pitch_rad[ok]) & np.isfinite(ref.sigma_pitch_rad[ok])
    return np.column_stack([t, ref.heading_rad[ok], np.where(pitch_ok, ref.pitch_rad[ok], np.nan),
                            ref.sigma_heading_rad[ok], np.where(pitch_ok, ref.sigma_pitch_rad[ok], np.nan)])[keep]


def _truth_reference(truth: evaluate.Truth, system_epochs: np.ndarray) -> tuple:
    """The simulated truth as the reference (t, r_ecef, name): at the reference system's epochs when the
    session has one (so both are scored from one set of bracketing rows: a day's brackets then take
    150 MB less), else every sample at about TRUTH_SCORING_HZ; either is enough for drift and outage
    maxima. Read block by block from a memory-mapped truth, whose pages are given back."""
    tt = truth.t
    if len(system_epochs):
        te = system_epochs[(system_epochs >= tt[0]) & (system_epochs <= tt[-1])]
        r, block = np.empty((len(te), 3)), outages_mod.ERRORS_BLOCK
        for a in range(0, len(te), block):
            r[a:a + block] = truth.at(te[a:a + block]).r_ecef
            truth.release()
        return te, r, "truth.npz"
    step = max(1, int(round(1.0 / (TRUTH_SCORING_HZ * float(np.median(np.diff(tt))))))) if len(tt) > 1 else 1
    out = (tt[::step], np.array(truth.r_ecef[::step]), "truth.npz")
    truth.release()
    return out


_REFERENCE_SYSTEM: dict = {}  # the last reference system read, under its file's (path, mtime, size)


def _reference_system(source: Path):
    """A session's reference system (``reference.csv``), if it has one; read once for the modes of one
    replay (--mode both read and parsed it twice: 0.03-0.06 s each for the default drive's)."""
    path = source / reference_mod.FILE_NAME
    if not (source.is_dir() and path.exists()):
        return None
    st = path.stat()
    key = (str(path.resolve()), st.st_mtime_ns, st.st_size)
    if _REFERENCE_SYSTEM.get("key") != key:
        _REFERENCE_SYSTEM.clear()
        _REFERENCE_SYSTEM.update(key=key, reference=reference_mod.load(source))
    return _REFERENCE_SYSTEM["reference"]


def reference_scores(t: np.ndarray, r_score: np.ndarray, ref: tuple, schedule: np.ndarray,
                     v: np.ndarray | None = None, update_t: np.ndarray | None = None, same_instant_s: float = 0.0
                     ) -> tuple[dict, dict, np.ndarray]:
    """Errors against a reference (t, r_ecef, name) and the per-outage drift: arrays, the scoring
    summary, and which reference epochs were used. With the solution's velocities and update times the
    solution is never interpolated across an update (``outages.solution_at``)."""
    use, e = outages_mod.errors_ned(t, r_score, ref[0], ref[1], v, update_t, same_instant_s)
    sc = outages_mod.score_errors(np.asarray(ref[0], float)[use], e, schedule)
    h = np.hypot(e[:, 0], e[:, 1])
    scoring = {"all": {"rms_h_m": float(np.sqrt(np.mean(h ** 2))) if len(h) else float("nan"),
                       "rms_v_m": float(np.sqrt(np.mean(e[:, 2] ** 2))) if len(h) else float("nan"),
                       "max_h_m": float(h.max()) if len(h) else float("nan")},
               **sc.summary()}
    arrays = dict(ref_err_ned_m=e, drift_t_s=sc.drift_t_s, drift_h_m=sc.drift_h_m, drift_v_m=sc.drift_v_m,
                  drift_outage=sc.drift_outage)
    return arrays, scoring, use


def _ins_aiding_end(run: flt.ChunkedRun, fixes: np.ndarray) -> float | None:
    """Time of the fix after which the filter was initialised (heading known): the last one an INS run
    gets. Only the chunks up to that point are run."""
    for sol in run.chunks(covariance=False):
        known = np.flatnonzero(sol.heading_known)
        if len(known):
            t_known = sol.t[known[0]]
            used = fixes[(fixes[:, 0] <= t_known) & np.isin(fixes[:, 9], (2, 3))]
            return float(used[-1, 0]) if len(used) else float(t_known)
    return None


@dataclass
class _Scored:
    """What a solution stream's brackets give against a reference."""

    arrays: dict
    summary: dict


def _score_stream(stream, ref, schedule, prefix: str = "") -> _Scored:
    rows = stream.brackets.rows()
    if ref is None or not len(ref[0]) or len(rows.get("t", ())) < 1:
        return _Scored({}, {})
    same_instant = 0.0 if stream.truth is not None and ref[2] == "truth.npz" else POS_TIME_RESOLUTION_S
    arrays, scoring, use = reference_scores(rows["t"], rows["r_score"], ref, schedule, rows.get("v"),
                                            stream.update_times(), same_instant)
    arrays.update(ref_t=ref[0][use], ref_r_ecef=ref[1][use], ref_outage=outages_mod.outage_index(ref[0][use], schedule))
    return _Scored({prefix + k: v for k, v in arrays.items()}, scoring)


def load_inputs(source: str | Path, *, modes=("loose",), config=None, overrides: dict | None = None,
                timing_method: str = "robust", gps_latency_s: float = DEFAULT_GPS_LATENCY_S,
                imu_latency_s: float = DEFAULT_IMU_LATENCY_S, truth: bool = True,
                nav: str | Path | None = None, force: bool = False) -> Inputs:
    """A session's or data set's inputs, decoded once for every mode asked for; a session that a
    receiver restart split in stretches is refused (:func:`load_stretches` gives each)."""
    stretches = load_stretches(source, modes=modes, config=config, overrides=overrides, timing_method=timing_method,
                               gps_latency_s=gps_latency_s, imu_latency_s=imu_latency_s, truth=truth, nav=nav,
                               force=force)
    if len(stretches) > 1:
        raise layouts.LogError(f"{source}: GPS time goes back {len(stretches) - 1} time(s) (receiver restarts): "
                            f"{len(stretches)} stretches, each to be replayed on its own")
    return stretches[0]


def load_stretches(source: str | Path, *, modes=("loose",), config=None, overrides: dict | None = None,
                   timing_method: str = "robust", gps_latency_s: float = DEFAULT_GPS_LATENCY_S,
                   imu_latency_s: float = DEFAULT_IMU_LATENCY_S, truth: bool = True,
                   nav: str | Path | None = None, force: bool = False) -> list[Inputs]:
    """The inputs of each stretch a session holds between receiver restarts (GPS time going back),
    each on its own time line and replayed on its own; one for a session without restarts or a
    data set (arguments as for :func:`load_inputs`; ``force``: a data set the doctor finds at odds with
    its declaration is replayed anyway)."""
    source = Path(source)
    if is_dataset(source):
        return [_dataset_inputs(source, config, dict(overrides or {}), modes, force)]
    overrides = dict(overrides or {})
    t0 = time.perf_counter()
    decs = _decode_stretches(source, config, overrides)
    decode_s = (time.perf_counter() - t0) / len(decs)
    out = []
    for j, dec in enumerate(decs):
        inp = _session_inputs(source, "tight" if "tight" in modes else "loose", config, timing_method,
                              gps_latency_s, imu_latency_s, truth, nav, overrides, dec=dec, decode_s=decode_s)
        if len(decs) > 1:
            inp.info["stretch"] = {"index": j + 1, "of": len(decs), "gps_span_s": list(inp.gnss_span)}
            back = ", ".join(f"by {before - after:.1f} s after GPS time of week {before:.1f} s"
                             for _, _, before, after in dec.gps.restarts)
            inp.info["warnings"].append(f"GPS time went back {back} (a receiver restart): stretch {j + 1} of "
                                        f"{len(decs)}, replayed on its own")
        out.append(inp)
    return out


def stretch_dir(j: int, n: int) -> str:
    """Sub-directory of stretch j (from 0) of n in a replay's output ('' for a session in one piece)."""
    return f"stretch-{j + 1}" if n > 1 else ""


def replay(source: str | Path, out: str | Path, *, mode: str = "loose", config=None, overrides: dict | None = None,
           timing_method: str = "robust", gps_latency_s: float = DEFAULT_GPS_LATENCY_S,
           imu_latency_s: float = DEFAULT_IMU_LATENCY_S, truth: bool = True,
           nav: str | Path | None = None, outages: str | outages_mod.OutageSpec | None = None,
           reference: str | Path | None = None, reference_q=(1,), point: str = "antenna",
           smooth: bool = False, covariance_every: int = 0, chunk_rows: int = flt.CHUNK_ROWS,
           aid_heading: bool = False, overlap: bool = True, force: bool = False,
           estimator: str | None = None) -> ReplayResult:
    """Replay a session directory or a data-set TOML (see the module doc); ``outages``: FIRST:LENGTH:PERIOD[:END];
    ``reference``: an RTKLIB .pos (its ``reference_q`` epochs) at the antenna point; ``point``: the point
    solution.pos gives (antenna or imu); ``smooth``: also the fixed-interval smoother (smoothed.parquet,
    smoothed.pos, run.json "smoothed"); ``covariance_every``: also the full covariance of every so many
    epochs (covariance.parquet); ``chunk_rows``: IMU samples per filter call (memory, not results);
    ``overlap``: the filter's next chunk runs on a second thread while this one is scored and written
    (results unchanged; off for one run per core, as Monte Carlo workers are). A session whose receiver
    restarted (GPS time going back) is replayed stretch by stretch into ``out/stretch-N``: the result
    is the first stretch's, with every stretch's in ``stretches``."""
    if mode not in MODES:
        raise ValueError(f"--mode {mode!r}: one of {', '.join(MODES)}")
    stretches = load_stretches(source, modes=(mode,), config=config, overrides=overrides,
                               timing_method=timing_method, gps_latency_s=gps_latency_s,
                               imu_latency_s=imu_latency_s, truth=truth, nav=nav, force=force)
    results = [run_mode(inp, Path(out) / stretch_dir(j, len(stretches)), mode=mode, overrides=overrides,
                        outages=outages, reference=reference, reference_q=reference_q, point=point, smooth=smooth,
                        covariance_every=covariance_every, chunk_rows=chunk_rows, aid_heading=aid_heading,
                        overlap=overlap, estimator=estimator) for j, inp in enumerate(stretches)]
    results[0].stretches = results
    return results[0]


def lever_arm_body_m(cfg: dict) -> np.ndarray:
    return np.broadcast_to(np.asarray(cfg.get("lever_arm_body_m", 0.0), float), (3,)).copy()


RESULT_FILES = (results.SOLUTION, results.SMOOTHED, results.UPDATES, results.COVARIANCE, results.SMALL,
                "solution.pos", "smoothed.pos", "config.toml", "run.json")


def run_mode(inp: Inputs, out: str | Path, **options) -> ReplayResult:
    """One filter mode over decoded inputs (``load_inputs``), written to ``out`` (see ``_run_mode``). A run
    that fails leaves no partial results behind: the files it writes are removed (the directory too,
    if it made it and it is left empty); a full disk is said so, naming the results directory."""
    out = Path(out)
    made = not out.exists()
    try:
        return _run_mode(inp, out, **options)
    except BaseException as e:
        for name in RESULT_FILES:
            (out / name).unlink(missing_ok=True)
        if made and out.is_dir() and not any(out.iterdir()):
            out.rmdir()
        if isinstance(e, OSError) and e.errno == errno.ENOSPC:
            raise OSError(e.errno, "no space left on the device for the results (the partial ones are removed)",
                          str(out)) from None
        raise


def _run_mode(inp: Inputs, out: Path, *, mode: str = "loose", overrides: dict | None = None,
             outages: str | outages_mod.OutageSpec | None = None, reference: str | Path | None = None,
             reference_q=(1,), point: str = "antenna", smooth: bool = False, covariance_every: int = 0,
             chunk_rows: int = flt.CHUNK_ROWS, aid_heading: bool = False, last_use: bool = False,
             overlap: bool = True, estimator=None) -> ReplayResult:
    """One filter mode over decoded inputs (``load_inputs``), written to ``out`` (see ``replay``);
    ``estimator``: a plug-in estimator, or its ``package.module:name``, run in the built-in filter's
    place (``gpsins.nav.estimator``), scored and written the same way;
    ``aid_heading``: the session's reference system's dual-antenna heading and pitch (``reference.csv``)
    aid the filter (then it no longer scores the attitude independently); ``last_use``: no later call
    uses ``inp``, so its IMU samples and pseudoranges are let go once the filter has run, before the
    scoring (a day's: 240 MB)."""
    if mode not in MODES:
        raise ValueError(f"--mode {mode!r}: one of {', '.join(MODES)}")
    if point not in POINTS:
        raise ValueError(f"--point {point!r}: one of {', '.join(POINTS)}")
    if mode == "tight" and inp.kind == "session" and inp.pseudoranges is None:
        raise ValueError(f"{inp.source}: inputs were decoded without pseudoranges (load_inputs modes)")
    source, out = inp.source, Path(out)
    overrides = dict(overrides or {})
    spec = outages_mod.parse(outages) if isinstance(outages, str) else outages
    clock = {k: v for k, v in inp.info.items() if k in ("decode_s", "align_s")}
    filter_mode = "loose" if mode == "ins" else mode
    spec = spec if spec is not None else inp.outage_spec
    schedule = outages_mod.schedule(spec, *inp.gnss_span) if spec is not None else np.zeros((0, 2))
    if spec is not None and not len(schedule):
        raise layouts.LogError(f"{source}: outages {spec.text()}: none falls inside the GNSS span, "
                            f"{inp.gnss_span[1] - inp.gnss_span[0]:.1f} s from its first epoch")

    ins_overrides = {"zero_velocity_updates": False} if mode == "ins" else {}
    cfg = nav_config.load_config(inp.base_config, {**inp.data_config, **overrides, **ins_overrides, "mode": filter_mode})
    fix_out = outages_mod.inside(inp.fixes[:, 0], schedule)
    fixes = inp.fixes[~fix_out]
    prs = inp.pseudoranges if filter_mode == "tight" else None
    n_imu, n_prs = len(inp.imu), len(prs) if prs is not None else 0
    if prs is not None and len(schedule):  # a copy only when something is left out (a day's table is 200 MB)
        prs = prs[~outages_mod.inside(prs[:, 0], schedule)]
    prs_removed = n_prs - len(prs) if prs is not None else 0
    tight = {}
    if filter_mode == "tight":
        tight = dict(pseudoranges=prs if prs is not None else np.zeros((0, 5)), ephemerides=inp.ephemerides,
                     klobuchar=inp.klobuchar, gps_time_offset_s=inp.week * gpstime.SECONDS_PER_WEEK)

    if estimator is not None and (mode == "ins" or smooth or aid_heading):
        raise ValueError(f"--estimator {estimator}: not with --mode ins, --smooth or --aid-heading (the built-in "
                         "filter's)")
    noise_fit = mount_fit = None
    # (A plug-in gets the configuration and fixes these make: what the built-in filter would run with.)
    if cfg.get("fit_noise") and filter_mode == "loose" and len(fixes):
        # The statistics from the recording: fitted on the fixes this run uses (outages removed),
        # without the vehicle constraint, whose mounting may not be known yet.
        t_fit = time.perf_counter()
        noise_fit = noise_from_data.fit_noise(inp.imu, fixes, {**cfg, "nonholonomic_constraint": False},
                                              mode=filter_mode)
        cfg, fixes = noise_from_data.scaled(cfg, fixes, noise_fit["factors"])
        clock["noise_fit_s"] = time.perf_counter() - t_fit
    if cfg.get("estimate_mounting") and cfg.get("nonholonomic_constraint") and filter_mode == "loose" and len(fixes):
        cfg, mount_fit = _with_estimated_mounting(inp.imu, fixes, cfg)

    ref_system = _reference_system(source)
    attitude = None
    if aid_heading:
        if ref_system is None:
            raise ValueError(f"{source}: --aid-heading: no dual-antenna reference ({reference_mod.FILE_NAME}) beside "
                             "the session")
        attitude = heading_aiding(ref_system, inp.week)
        if mode == "ins":
            raise ValueError(f"{source}: --aid-heading and --mode ins: free inertial navigation takes no aiding")

    def make_run(cfg_run: dict, fixes_run: np.ndarray, record: bool) -> flt.ChunkedRun:
        return flt.ChunkedRun(inp.imu, fixes_run, cfg_run, mode=filter_mode, record=record, chunk_rows=chunk_rows,
                              attitude=attitude, overlap=overlap, **tight)

    t2 = time.perf_counter()
    free_from, searched = None, None
    if mode == "ins":
        first = make_run(cfg, fixes, False)
        searched = first.heading_search
        free_from = _ins_aiding_end(first, fixes)
        if free_from is None:
            raise ValueError(f"{source}: --mode ins: the heading never became known, so free navigation never "
                             "started (set initial_yaw_deg, or use data that moves faster than heading_min_speed_mps)")
        if searched and searched["yaw_deg"] is not None:  # the searched heading: aided over the search's fixes
            cfg = flt.starting_at_yaw(cfg, searched["yaw_deg"], searched["sigma_deg"])
            used = fixes[(fixes[:, 0] <= searched["t_end"]) & np.isin(fixes[:, 9], (2, 3))]
            free_from = float(used[-1, 0]) if len(used) else free_from
        fixes = fixes[fixes[:, 0] <= free_from]
    if estimator is not None:
        est = estimator_mod.load(estimator) if isinstance(estimator, str) else estimator
        estimator = estimator if isinstance(estimator, str) else getattr(est, "__name__", type(est).__name__)
        run = estimator_mod.PluginRun(est, estimator, estimator_mod.EstimatorInputs(
            filter_mode, inp.week, np.asarray(inp.imu[:], dtype=float), fixes, lever_arm_body_m(cfg), dict(cfg),
            prs[:] if prs is not None else None, inp.ephemerides, inp.klobuchar, schedule), chunk_rows)
    else:
        run = make_run(cfg, fixes, smooth)
    if searched:
        run.heading_search = searched
    clock["filter_setup_s"] = time.perf_counter() - t2

    # Scoring against a reference: a .pos at the antenna point, else a session's truth at the IMU.
    found = inp.truth
    ref = inp.reference
    if reference is not None:
        f = dataset_mod.load_reference(reference, reference_q)
        ref = (f.t_abs - inp.week * gpstime.SECONDS_PER_WEEK, f.r_ecef, f.source)
        t_imu = (float(inp.imu[0, 0]), float(inp.imu[len(inp.imu) - 1, 0]))
        if not np.any((ref[0] >= t_imu[0]) & (ref[0] <= t_imu[1])):
            raise layouts.LogError(f"{reference}: none of its {len(ref[0])} epochs (Q {list(reference_q)}) falls inside "
                                f"the IMU's span (GPS week {inp.week}, {t_imu[0]:.1f} to {t_imu[1]:.1f} s of week)")
    scored_point = "antenna"
    sys_epochs = (ref_system.gps_seconds() - inp.week * gpstime.SECONDS_PER_WEEK) if ref_system else np.zeros(0)
    if ref is None and found:
        ref, scored_point = _truth_reference(found[0], sys_epochs), "imu"
    has_ref = ref is not None and len(ref[0]) > 0
    score_sched = schedule
    bracket_epochs = np.concatenate([ref[0] if has_ref else np.zeros(0), sys_epochs])
    lever = lever_arm_body_m(cfg)

    out.mkdir(parents=True, exist_ok=True)
    for stale in (results.SMOOTHED, results.COVARIANCE, "smoothed.pos"):  # from an earlier run into this directory
        (out / stale).unlink(missing_ok=True)
    what = f"mode {mode}, {inp.kind} {source.name}, {point} point"

    def stream(table: str, pos: str, note: str, newest_first: bool = False, cov: bool = False) -> solution.Stream:
        return solution.Stream(out / table, out / pos, inp.week, note, lever, inp.fixes[:, 0], inp.fix_sats,
                               truth=found[0] if found else None, score_point=scored_point, pos_point=point,
                               bracket_epochs=bracket_epochs, newest_first=newest_first,
                               covariance_path=out / results.COVARIANCE if cov else None,
                               covariance_every=covariance_every)

    t3 = time.perf_counter()
    forward = stream(results.SOLUTION, "solution.pos", what, cov=covariance_every > 0)
    updates = results.TableWriter(out / results.UPDATES)
    events: dict[str, list] = {"t": [], "kind": [], "value": []}
    update_kinds: dict[int, int] = {}
    stat_columns = ("kind", "dof", "nis", "accepted", "r_scale", "innovation", "innovation_sigma")
    update_cols: dict[str, list] = {k: [] for k in stat_columns}
    write_s = 0.0
    time_offset = None  # the last epoch's estimate and sigma (s), with estimate_time_offset
    for sol in run.chunks():
        if sol.time_offset is not None and len(sol.t):
            time_offset = (float(sol.time_offset[-1]), float(sol.time_offset_sigma[-1]))
        w0 = time.perf_counter()
        forward.add(sol, forward.epochs)
        updates.append(sol.updates)
        write_s += time.perf_counter() - w0
        for k in stat_columns:
            update_cols[k].append(np.asarray(sol.updates[k]))
        for k in events:
            events[k].extend(np.asarray(sol.events.get(k, ())).tolist())
        for k, n in zip(*np.unique(sol.updates["kind"], return_counts=True)):
            update_kinds[int(k)] = update_kinds.get(int(k), 0) + int(n)
    forward.close()
    updates.close()
    clock["filter_s"] = time.perf_counter() - t3 - write_s
    if forward.epochs == 0:
        raise measurements.logs.LogError(f"{source}: the filter never initialised (no usable fix after levelling)")
    counters = run.counters
    sources = noise_from_data.source_stats({k: np.concatenate(v) if v else np.zeros(0)
                                            for k, v in update_cols.items()})
    if last_use:
        run.release_inputs()
        inp.imu = inp.pseudoranges = prs = tight = None
    if mode == "ins":  # the whole free stretch is one outage
        score_sched = np.array([[free_from, max(forward.last_t, free_from) + 1e-6]])

    smoothed_summary = None
    if smooth:
        ts = time.perf_counter()
        back = stream(results.SMOOTHED, "smoothed.pos", what + ", fixed-interval smoothed", newest_first=True)
        info = run.smooth(lambda first, sol: back.add(sol, first))
        back.close()
        clock["smooth_s"] = time.perf_counter() - ts
        smoothed_summary = {"info": info}
        if back.score is not None and back.score.summary():
            smoothed_summary["errors"] = back.score.summary()
        sm_scored = _score_stream(back, ref, score_sched, results.SMOOTH_PREFIX)
        if sm_scored.summary:
            smoothed_summary["scoring"] = sm_scored.summary

    t4 = time.perf_counter()
    small = dict(week=np.int64(inp.week), fixes=inp.fixes, fix_sats=inp.fix_sats, lever_arm_body_m=lever,
                 outages=schedule)
    if found:
        small.update({k: v for k, v in found[1].items() if k != "simulation"})  # arrays only
    scoring = {}
    if has_ref:
        scored = _score_stream(forward, ref, score_sched)
        small.update(scored.arrays)
        scoring = {"reference": str(ref[2]), "point": scored_point,
                   "n_reference_epochs": int(len(scored.arrays.get("ref_t", ()))), **scored.summary}
        if mode == "ins":
            scoring["ins_free_from"] = free_from
    if smooth:
        small.update(sm_scored.arrays)
    np.savez(out / results.SMALL, **small)
    reference_system = _score_reference_system(ref_system, inp.week, forward.brackets.rows())
    config_text = nav_config.to_toml(cfg)
    (out / "config.toml").write_text(config_text, encoding="utf-8")
    clock["write_s"] = write_s + time.perf_counter() - t4
    clock["total_s"] = sum(v for k, v in clock.items())
    info = {k: v for k, v in inp.info.items() if k not in ("decode_s", "align_s")}
    event_list = [{"t": float(t), "kind": flt.EVENT_KINDS.get(int(k), str(int(k))), "value": float(v)}
                  for t, k, v in zip(events["t"], events["kind"], events["value"])]
    summary = {"session": info.pop("session", str(source)), "kind": inp.kind, "mode": mode,
               "alignment": info.pop("alignment", {}), "counters": counters,
               "imu_gaps_longer_than_max_gap": info.pop("imu_gaps_longer_than_max_gap", []),
               "reinitialisations": {"count": int(counters.get("imu_gap_restarts", 0)),
                                     "at_t": [e["t"] for e in event_list if e["kind"] == "imu_gap_restart"],
                                     "how": "the filter restarted after an IMU gap longer than max_gap_s: attitude "
                                            "and biases kept, heading unknown, covariance inflated"},
               "gnss_resets": {"count": int(counters.get("gnss_resets", 0)),
                               "at_t": [e["t"] for e in event_list if e["kind"] == "gnss_reset"]},
               "events": event_list,
               "warnings": info.pop("warnings", []),
               "skipped": info.pop("skipped", {}), "fixes_after_end": run.fixes_after_end,
               "wall_time_s": clock, "imu_samples": n_imu, "epochs": forward.epochs,
               "errors": forward.score.summary() if forward.score is not None else {},
               "update_kinds": {flt.UPDATE_KINDS[k]: n for k, n in sorted(update_kinds.items())},
               "sources": sources, "noise_fit": noise_fit, "mounting_fit": mount_fit,
               "health": health_lines(counters, sources),
               "solution_point": point,
               "heading_aiding": ({"source": reference_mod.FILE_NAME, "epochs": int(len(attitude)),
                                   "interval_s": HEADING_AIDING_INTERVAL_S} if attitude is not None else None),
               "outages": {"spec": spec.text() if spec is not None else None, "schedule": schedule.tolist(),
                           "gnss_first_t": inp.gnss_span[0], "gnss_last_t": inp.gnss_span[1],
                           "fixes_removed": int(fix_out.sum()),
                           "pseudoranges_removed": int(prs_removed)},
               "scoring": scoring}
    if reference_system:
        summary["reference_system"] = reference_system
    if run.heading_search is not None:
        summary["heading_search"] = run.heading_search
    if estimator is not None:
        summary["estimator"] = estimator
    if mode == "ins":
        summary["ins"] = {"aiding_until_t": free_from, "fixes_used": int(len(fixes)),
                          "how": "loose filter fed the fixes up to the one that completed the initialisation "
                                 "(heading known); zero-velocity and zero-rate updates off"}
    if time_offset is not None:
        # The residual the filter found on top of the declared offset (a data set's [imu] time_offset_s).
        summary["time_offset"] = {"estimate_s": time_offset[0], "sigma_s": time_offset[1],
                                  "applied_s": info.get("imu_time_offset_s"),  # None: not a data set
                                  "how": "the IMU stamps lag GNSS time by estimate_s after applied_s: add it to "
                                         "[imu] time_offset_s (final epoch of the forward pass)"}
    if smoothed_summary is not None:
        summary["smoothed"] = smoothed_summary
    # What made this result: enough to make it again.
    summary["provenance"] = {"gpsins": __version__, "command": shlex.join(["gpsins", *sys.argv[1:]])
                             if Path(sys.argv[0]).name in ("gpsins", "__main__.py", "cli.py") else None,
                             "config_sha256": hashlib.sha256(config_text.encode()).hexdigest(),
                             "source": str(source),
                             "simulation": (inp.truth[1].get("simulation") if inp.truth is not None else None)}
    if "stretch" in info:  # one of the stretches a receiver restart split the session into
        summary["stretch"] = info.pop("stretch")
    if "doctor" in info:  # what the data-set doctor measured
        summary["doctor"] = info.pop("doctor")
    if info:
        summary["dataset"] = info
    (out / "run.json").write_text(results.json_text(summary) + "\n", encoding="utf-8")
    return ReplayResult(out, mode, summary)
