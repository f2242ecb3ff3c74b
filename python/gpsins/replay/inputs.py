"""What a replay feeds the filter (``Inputs``): a session decoded and aligned (stretch by stretch when its
receiver restarted), or a data set read, with what the data say of the filter's configuration and
the simulated truth beside a session.
"""

from __future__ import annotations

import json
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
from ..session import measurements_ubx
from ..timing import alignment
from ..formats import rinex
from ..formats.gpstime import SECONDS_PER_WEEK


DEFAULT_GPS_LATENCY_S = 0.0205  # receiver's epoch-to-first-byte delay (assumed 20 ms) + the logger's
DEFAULT_IMU_LATENCY_S = 0.0005
UNKNOWN_CN0_DBHZ = 99.0  # what the tight filter is given for a pseudorange whose C/N0 the file does not state
# An outside receiver's oscillator unless its data set says otherwise: a free-running TCXO, whose frequency
# random walk (h_-2 = 2e-20) drives the clock drift by sqrt(2 pi^2 h_-2) c = 0.19 m/s per sqrt(s). The
# preset's 0.01 is the simulated receiver's steered clock; the walk's u-blox drift moves by 0.37 m/s within
# 1 s and ramps 15 m/s over its 134 s, which 0.01 cannot follow once Doppler pins the drift (the tight walk's
# vertical error went to 17 m).
REAL_RECEIVER_CLOCK_DRIFT_NOISE_MPS_PER_SQRT_S = 0.19


def load_session_truth(directory: Path, t_offset: float) -> tuple[evaluate.Truth, dict] | None:
    """The simulated truth next to a session (session dir or its parent), on the replay's time base."""
    for p in (directory / "truth.npz", directory.parent / "truth.npz"):
        if p.exists():
            from ..formats.truth import open_truth  # memory-mapped: a day-long truth is not read whole

            z = open_truth(p)
            tow = z["tow_s"] + (int(z["gps_week"]) * SECONDS_PER_WEEK) - t_offset
            evaluate.release_pages(z["tow_s"])
            model = json.loads(str(z["model_json"])) if "model_json" in z else {}
            extra = {"seg_labels": z["segment_labels"], "seg_t": z["segment_t"] + float(z["t0_tow_s"]) +
                     int(z["gps_week"]) * SECONDS_PER_WEEK - t_offset,
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
        uere = nav_config.value(nav_config.load_config(config, overrides or {}), "fix_uere_m")
        return [measurements_ubx.decode_session(session, uere)]
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
        inp.pseudoranges = (prs if isinstance(prs, nav_inputs.PseudorangeColumns)
                            else nav_inputs.PseudorangeColumns.compact(prs))
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
    if (ds.antenna_sigma_m > 0).any():
        derived["lever_arm_sigma_m"] = ds.antenna_sigma_m.tolist()
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
