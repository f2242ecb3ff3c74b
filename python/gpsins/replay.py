"""Replay a logger session or a data set through the filter.

session directory -> decoded measurements -> time alignment -> filter -> results directory;
data-set TOML (``gpsins.dataset``) -> decoded files -> filter -> the same results directory:

- ``results.npz``: the solution (see ``RESULT_ARRAYS``), the receiver's fixes,
  every update, and, when the session has a truth file, the errors;
- ``solution.pos``: RTKLIB-style positions (GPST, latitude, longitude, height,
  standard deviations), for RTKLIB's plot tools and comparisons;
- ``config.toml``: the exact filter configuration used;
- ``run.json``: counters, what was skipped and why, the alignment's summary,
  timings and summary statistics; with a reference (``--reference``, a data set's
  ``[scoring]``, or a session's simulated truth) the errors against it and, with
  ``--outages``, the per-outage drift (``outages.Score.summary``).

What a data set gives the filter (each only where neither the data set's ``[filter]``
table nor ``--set`` names the key itself): ``lever_arm_body_m`` from ``[gnss] antenna_m``;
``imu_rate_hz`` from the median IMU interval (the core's gap bridging and standstill
window use it); ``use_fix_velocity`` when the fixes carry velocities and
``fix_velocity_sigma_mps`` from their stated sigmas (``dataset.velocity_sigma``, for fixes that
state none); ``pseudorange_decimation`` so that the tight
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

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import dataset as dataset_mod, evaluate, filter as flt, measurements, outages as outages_mod
from . import measurements_ubx, reference as reference_mod, timing
from .readers import rinex

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
    "upd_*": "updates: t, kind, id, dof, nis, gate, accepted, innovation (3), innovation_sigma (3)",
    "err_ned_m": "position error (estimate - truth) NED", "err_ypr_deg": "attitude error",
    "err_v_ned_mps": "velocity error NED", "nees9": "NEES of the 9 navigation states",
    "seg_labels": "truth segment labels", "seg_t": "truth segments' start and end times",
    "sigma_v_ned_mps": "velocity sigma north, east, down",
    "clock": "tight mode: receiver clock bias (m) and drift (m/s); their sigmas are the last two of `sigma`",
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
POINTS = ("antenna", "imu")


@dataclass
class ReplayResult:
    out: Path
    mode: str
    summary: dict


def _nav_sigmas(sol: flt.Solution) -> tuple[np.ndarray, np.ndarray]:
    llh = sol.llh()
    c_en = evaluate.c_en(llh[:, 0], llh[:, 1])
    p = sol.covariance
    pos = np.swapaxes(c_en, -1, -2) @ p[:, 6:9, 6:9] @ c_en
    # Body-side attitude error dtheta -> NED axes: C_nb dtheta.
    c_eb = flt._core.dcm_from_quat(sol.q_eb)
    c_nb = np.swapaxes(c_en, -1, -2) @ c_eb
    att = c_nb @ p[:, 0:3, 0:3] @ np.swapaxes(c_nb, -1, -2)
    return (np.sqrt(np.diagonal(pos, axis1=1, axis2=2)), np.degrees(np.sqrt(np.diagonal(att, axis1=1, axis2=2))))


def write_pos(path: Path, week: int, sol: flt.Solution, sigma_ned: np.ndarray, sats: np.ndarray, every: int = 1,
              note: str = "") -> None:
    """RTKLIB-style .pos (lat/lon/height, GPST epochs); Q = 5 (single) for an INS solution."""
    llh = sol.llh()
    idx = np.arange(0, len(sol.t), every)
    lines = ["% program   : gpsins replay", f"% {note}" if note else "%",
             "% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)",
             "%  GPST                   latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)"
             "  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio"]
    times = rinex.gpst_text(week * measurements.SECONDS_PER_WEEK + sol.t[idx])
    for k, ts in zip(idx, times):
        lat, lon = np.degrees(llh[k, :2])
        sn, se, sd = sigma_ned[k]
        lines.append(f"{ts} {lat:14.9f} {lon:14.9f} {llh[k, 2]:10.4f} {5:3d} {int(sats[k]):3d} {sn:8.4f} {se:8.4f} "
                     f"{sd:8.4f} {0.0:8.4f} {0.0:8.4f} {0.0:8.4f} {0.0:6.2f} {0.0:6.1f}")
    path.write_text("\n".join(lines) + "\n", encoding="ascii")


def load_session_truth(directory: Path, t_offset: float) -> tuple[evaluate.Truth, dict] | None:
    """The simulated truth next to a session (session dir or its parent), on the replay's time base."""
    for p in (directory / "truth.npz", directory.parent / "truth.npz"):
        if p.exists():
            from .sim.truthfile import open_truth  # memory-mapped: a day-long truth is not read whole

            z = open_truth(p)
            tow = z["tow_s"] + (int(z["gps_week"]) * 604800.0) - t_offset
            extra = {"seg_labels": z["segment_labels"], "seg_t": z["segment_t"] + float(z["t0_tow_s"]) +
                     int(z["gps_week"]) * 604800.0 - t_offset}
            return evaluate.Truth(tow, z["r_ecef"], z["v_ecef"], z["q_eb"]), extra
    return None


@dataclass
class Inputs:
    """What a replay feeds the filter, on one time base: GPS seconds since the start of ``week``."""

    source: Path
    kind: str  # "session" | "dataset"
    week: int
    imu: np.ndarray  # (n, 7)
    fixes: np.ndarray  # (m, 10) every fix the receiver (or file) gave
    fix_sats: np.ndarray  # (m,)
    gnss_span: tuple[float, float]  # first and last GNSS epoch: the outage schedule's origin
    pseudoranges: np.ndarray | None = None  # (k, 5) tight
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


def _session_inputs(session: Path, mode: str, config, timing_method: str, gps_latency_s: float,
                    imu_latency_s: float, truth: bool, nav, overrides: dict) -> Inputs:
    t0 = time.perf_counter()
    if measurements_ubx.is_ublox(session):  # a u-blox receiver: NAV-PVT fixes carry its own accuracy
        dec = measurements_ubx.decode_session(session, flt.load_config(config, overrides or {})["fix_uere_m"])
    else:
        dec = measurements.decode_session(session)
    decode_s = time.perf_counter() - t0
    t1 = time.perf_counter()
    al = timing.align(dec.gps.tow, dec.gps.stamps, dec.gps.week, dec.imu.stamps, dec.imu.counter, dec.imu.rate_hz,
                      method=timing_method, gps_latency_s=gps_latency_s, imu_latency_s=imu_latency_s)
    align_s = time.perf_counter() - t1
    imu = np.column_stack([al.imu_t, dec.imu.dtheta_rad, dec.imu.dv_mps])
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
        inp.pseudoranges, inp.ephemerides, inp.klobuchar = dec.gps.pseudorange_table(), ephs, klob
    inp.truth = load_session_truth(session, dec.gps.week * measurements.SECONDS_PER_WEEK) if truth else None
    max_gap = float(flt.load_config(config, overrides).get("max_gap_s", 0.5))
    inp.info = {"session": str(session), "alignment": al.summary(), "decode_s": decode_s, "align_s": align_s,
                "imu_gaps_longer_than_max_gap": al.gap_list(min_s=max_gap) if timing_method == "robust" else [],
                "warnings": al.warnings if timing_method == "robust" else [], "skipped": dict(dec.skipped)}
    return inp


def _spp_fixes(pr, nav, t0: float) -> tuple[np.ndarray, np.ndarray]:
    """Single-point fixes from pseudoranges (a RINEX data set has no receiver fixes): they start the tight
    filter and aid the loose one; hdop/vdop are the solution's DOPs."""
    from . import _core
    store = nav.store()
    rows, sats = [], []
    guess = np.zeros(3)
    for t, prns, prs in pr.epochs():
        r = _core.gnss.spp(store, t, prns, prs, nav.alpha, nav.beta, 10.0, True, True, True, True, guess)
        if r["ok"]:
            guess = r["r_ecef"]
            rows.append([t - t0, *r["r_ecef"], np.nan, np.nan, np.nan, r["hdop"], r["vdop"], 2.0])
            sats.append(r["n_used"])
    return np.array(rows, float).reshape(-1, 10), np.array(sats, int)


def _dataset_inputs(path: Path, config, overrides: dict) -> Inputs:
    t0 = time.perf_counter()
    ds = dataset_mod.load(path)
    decode_s = time.perf_counter() - t0
    first, last = ds.gnss_span()
    week = int(min(first, ds.imu.t_abs[0]) // measurements.SECONDS_PER_WEEK)
    t_week = week * measurements.SECONDS_PER_WEEK
    imu = np.column_stack([ds.imu.t_abs - t_week, ds.imu.dtheta_rad, ds.imu.dv_mps])
    explicit = set(ds.filter_table) if config is None else set(_config_keys(config))
    explicit |= set(overrides)
    base = config if config is not None else (dict(ds.filter_table) or None)
    cfg0 = flt.load_config(base, overrides)
    derived: dict = {"lever_arm_body_m": ds.antenna_m.tolist()}
    dt = np.diff(imu[:, 0])
    dt = dt[dt > 0]
    if len(dt):
        derived["imu_rate_hz"] = float(1.0 / np.median(dt))
    uere = float(cfg0["fix_uere_m"])
    if ds.fixes is not None and len(ds.fixes):
        fixes = dataset_mod.fix_table(ds.fixes, t_week, uere, ds.sigma_floor_m, ds.sigma_default_m,
                                      ds.velocity_sigma_floor_mps)
        sats = ds.fixes.ns.astype(int)
        vs = dataset_mod.velocity_sigma(ds.fixes, ds.velocity_sigma_floor_mps)
        if vs is not None:
            # Per-fix velocity sigmas travel in the fix table; this median only stands in where a fix has none.
            derived.update(use_fix_velocity=True, fix_velocity_sigma_mps=vs, fix_velocity_sigma_hdop_scaled=False)
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
        ep = np.unique(ds.pseudoranges.t_abs)
        if len(ep) > 1:
            rate = 1.0 / float(np.median(np.diff(ep)))
            derived["pseudorange_decimation"] = max(1, int(round(rate)))  # about one epoch per second
    # A car's body axes are its vehicle axes (dataset spec): its heading is its course, and it takes the
    # non-holonomic constraint; anything else may point away from where it goes (handheld).
    derived["platform"] = "vehicle" if ds.vehicle_kind == "car" else "handheld"
    if ds.vehicle_kind == "car":
        derived["nonholonomic_constraint"] = True
    inp.data_config = {k: v for k, v in derived.items() if k not in explicit}
    if ds.reference is not None:
        inp.reference = (ds.reference.t_abs - t_week, ds.reference.r_ecef, ds.reference.source)
    n_fix_q = {dataset_mod.Q_NAMES.get(int(q), str(q)): int(n) for q, n in
               zip(*np.unique(ds.fixes.q, return_counts=True))} if ds.fixes is not None else {}
    inp.info = {"dataset": str(path), "name": ds.name, "decode_s": decode_s, "skipped": dict(ds.skipped),
                "warnings": list(ds.notes), "imu_to_body": ds.imu_to_body.tolist(),
                "imu_time_offset_s": ds.imu_time_offset_s, "antenna_m": ds.antenna_m.tolist(),
                "gnss_format": ds.gnss_format, "vehicle_kind": ds.vehicle_kind, "fix_quality": n_fix_q,
                "from_data": inp.data_config,
                "ephemerides_prn": ds.navigation.prns() if ds.navigation is not None else []}
    return inp


def _config_keys(config) -> list[str]:
    """The keys a --config source names itself (a preset names none)."""
    if isinstance(config, dict):
        return list(config)
    if str(config) in flt.PRESETS and not Path(str(config)).suffix:
        return []
    import tomllib
    try:
        data = tomllib.loads(Path(config).read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError):
        return []  # load_config reports it
    return list(data.get("filter", data))


def _filter(inp: Inputs, cfg: dict, mode: str, fixes: np.ndarray, prs: np.ndarray | None, smooth: bool = False
            ) -> flt.Solution:
    tight = {}
    if mode == "tight":
        tight = dict(pseudoranges=prs if prs is not None else np.zeros((0, 5)), ephemerides=inp.ephemerides,
                     klobuchar=inp.klobuchar, gps_time_offset_s=inp.week * measurements.SECONDS_PER_WEEK)
    return flt.run(inp.imu, fixes, cfg, mode=mode, covariance=True, smooth=smooth, **tight)


def _score_reference_system(source: Path, week: int, sol: flt.Solution) -> dict:
    """Errors against the session's own reference system (RTK position and dual-antenna heading
    and pitch, ``reference.csv`` beside the session), as a real campaign scores without truth."""
    if not (source.is_dir() and (source / reference_mod.FILE_NAME).exists()):
        return {}
    ref = reference_mod.load(source)
    ypr = sol.ypr()
    e = reference_mod.compare(ref, week * measurements.SECONDS_PER_WEEK + sol.t, sol.r_ecef, ypr[:, 0], ypr[:, 1])
    return {"file": reference_mod.FILE_NAME, "damaged_lines": len(ref.damaged_lines), **e.summary()}


def _ins_aiding_end(sol: flt.Solution, fixes: np.ndarray) -> float | None:
    """Time of the fix after which the filter was initialised (heading known): the last one an INS run gets."""
    known = np.flatnonzero(sol.heading_known)
    if not len(known):
        return None
    t_known = sol.t[known[0]]
    used = fixes[(fixes[:, 0] <= t_known) & np.isin(fixes[:, 9], (2, 3))]
    return float(used[-1, 0]) if len(used) else float(t_known)


def antenna_positions(sol: flt.Solution, lever_arm_body_m) -> np.ndarray:
    """ECEF position of the antenna: r + C_eb lever arm."""
    lever = np.broadcast_to(np.asarray(lever_arm_body_m, float), (3,))
    if not np.any(lever) or not len(sol.t):
        return sol.r_ecef.copy()
    return sol.r_ecef + flt._core.dcm_from_quat(sol.q_eb) @ lever


def replay(source: str | Path, out: str | Path, *, mode: str = "loose", config=None, overrides: dict | None = None,
           timing_method: str = "robust", gps_latency_s: float = DEFAULT_GPS_LATENCY_S,
           imu_latency_s: float = DEFAULT_IMU_LATENCY_S, truth: bool = True,
           nav: str | Path | None = None, outages: str | outages_mod.OutageSpec | None = None,
           reference: str | Path | None = None, reference_q=(1,), point: str = "antenna",
           smooth: bool = False) -> ReplayResult:
    """Replay a session directory or a data-set TOML (see the module doc); ``outages``: FIRST:LENGTH:PERIOD[:END];
    ``reference``: an RTKLIB .pos (its ``reference_q`` epochs) at the antenna point; ``point``: the point
    solution.pos gives (antenna or imu); ``smooth``: also the fixed-interval smoother (smoothed.pos,
    ``smooth_*`` arrays, run.json "smoothed")."""
    if mode not in MODES:
        raise ValueError(f"--mode {mode!r}: one of {', '.join(MODES)}")
    if point not in POINTS:
        raise ValueError(f"--point {point!r}: one of {', '.join(POINTS)}")
    source, out = Path(source), Path(out)
    overrides = dict(overrides or {})
    spec = outages_mod.parse(outages) if isinstance(outages, str) else outages
    clock = {}
    filter_mode = "loose" if mode == "ins" else mode
    if is_dataset(source):
        inp = _dataset_inputs(source, config, overrides)
    else:
        inp = _session_inputs(source, filter_mode, config, timing_method, gps_latency_s, imu_latency_s, truth, nav,
                              overrides)
    clock["decode_s"] = inp.info.pop("decode_s")
    if "align_s" in inp.info:
        clock["align_s"] = inp.info.pop("align_s")
    spec = spec if spec is not None else inp.outage_spec
    schedule = outages_mod.schedule(spec, *inp.gnss_span) if spec is not None else np.zeros((0, 2))

    ins_overrides = {"zero_velocity_updates": False} if mode == "ins" else {}
    cfg = flt.load_config(inp.base_config, {**inp.data_config, **overrides, **ins_overrides, "mode": filter_mode})
    fix_out = outages_mod.inside(inp.fixes[:, 0], schedule)
    fixes = inp.fixes[~fix_out]
    prs = inp.pseudoranges
    if prs is not None:
        prs = prs[~outages_mod.inside(prs[:, 0], schedule)]

    t2 = time.perf_counter()
    sol = _filter(inp, cfg, filter_mode, fixes, prs, smooth)
    free_from = None
    if mode == "ins":
        free_from = _ins_aiding_end(sol, fixes) if len(sol.t) else None
        if free_from is None:
            raise ValueError(f"{source}: --mode ins: the heading never became known, so free navigation never "
                             "started (set initial_yaw_deg, or use data that moves faster than heading_min_speed_mps)")
        searched = sol.extra.get("heading_search")
        if searched and searched["yaw_deg"] is not None:  # the searched heading: aided over the search's fixes
            cfg = flt._merge(cfg, {"initial_yaw_deg": searched["yaw_deg"],
                                   "heading_sigma_deg": searched["sigma_deg"]})
            used = fixes[(fixes[:, 0] <= searched["t_end"]) & np.isin(fixes[:, 9], (2, 3))]
            free_from = float(used[-1, 0]) if len(used) else free_from
        fixes = fixes[fixes[:, 0] <= free_from]
        sol = _filter(inp, cfg, filter_mode, fixes, prs, smooth)
        if searched:
            sol.extra["heading_search"] = searched
    clock["filter_s"] = time.perf_counter() - t2
    if len(sol.t) == 0:
        raise measurements.logs.LogError(f"{source}: the filter never initialised (no usable fix after levelling)")
    t3 = time.perf_counter()

    fix_t = inp.fixes[:, 0]
    k = np.clip(np.searchsorted(fix_t, sol.t, side="right") - 1, 0, max(len(fix_t) - 1, 0))
    sats = inp.fix_sats[k] if len(fix_t) else np.zeros(len(sol.t), int)
    lever = np.broadcast_to(np.asarray(cfg.get("lever_arm_body_m", 0.0), float), (3,))
    r_ant = antenna_positions(sol, lever)
    arrays = dict(t=sol.t, week=np.int64(inp.week), **solution_arrays(sol), standstill=sol.standstill,
                  heading_known=sol.heading_known, fixes=inp.fixes, fix_sats=inp.fix_sats,
                  lever_arm_body_m=lever, outages=schedule)
    sigma_ned = arrays["sigma_ned_m"]
    arrays.update({f"upd_{k}": v for k, v in sol.updates.items()})
    stats = {}
    found = inp.truth
    if found:
        err_arrays, stats = truth_errors(sol, found[0])
        arrays.update(err_arrays, **found[1])

    # Scoring against a reference: a .pos at the antenna point, else a session's truth at the IMU.
    ref = inp.reference
    if reference is not None:
        f = dataset_mod.load_reference(reference, reference_q)
        ref = (f.t_abs - inp.week * measurements.SECONDS_PER_WEEK, f.r_ecef, f.source)
    scored_point = "antenna"
    if ref is None and found:
        ref, scored_point = (found[0].t, found[0].r_ecef, "truth.npz"), "imu"
    scoring = {}
    r_score = r_ant if scored_point == "antenna" else sol.r_ecef
    if ref is not None and len(ref[0]):
        score_sched = schedule
        if mode == "ins":
            score_sched = np.array([[free_from, max(float(sol.t[-1]), free_from) + 1e-6]])
        ref_arrays, scoring, use = reference_scores(sol.t, r_score, ref, score_sched)
        arrays.update(ref_arrays, ref_t=ref[0][use], ref_r_ecef=ref[1][use],
                      ref_outage=outages_mod.outage_index(ref[0][use], score_sched))
        scoring = {"reference": str(ref[2]), "point": scored_point, "n_reference_epochs": int(use.sum()), **scoring}
        if mode == "ins":
            scoring["ins_free_from"] = free_from
    arrays["r_point_ecef"] = r_score if scored_point == "imu" else r_ant
    reference_system = _score_reference_system(source, inp.week, sol)
    smoothed = None
    if smooth and "smoothed" in sol.extra:
        from . import smoothing
        sm_arrays, sm_summary, sm, sm_ant, sm_sigma_ned = smoothing.results(
            sol, found, ref, scored_point, lever, score_sched if ref is not None and len(ref[0]) else schedule)
        arrays.update(smoothing.prefixed(sm_arrays))
        smoothed = (sm_summary, sm if point == "imu" else _with_positions(sm, sm_ant), sm_sigma_ned)

    out.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out / "results.npz", **arrays)
    pos_sol = sol if point == "imu" else _with_positions(sol, r_ant)
    write_pos(out / "solution.pos", inp.week, pos_sol, sigma_ned, sats,
              note=f"mode {mode}, {inp.kind} {source.name}, {point} point")
    if smoothed is not None:
        write_pos(out / "smoothed.pos", inp.week, smoothed[1], smoothed[2], sats,
                  note=f"mode {mode}, {inp.kind} {source.name}, {point} point, fixed-interval smoothed")
    (out / "config.toml").write_text(flt.to_toml(cfg), encoding="utf-8")
    clock["write_s"] = time.perf_counter() - t3
    clock["total_s"] = sum(v for v in clock.values())
    info = dict(inp.info)
    events = sol.event_list()
    summary = {"session": info.pop("session", str(source)), "kind": inp.kind, "mode": mode,
               "alignment": info.pop("alignment", {}), "counters": sol.counters,
               "imu_gaps_longer_than_max_gap": info.pop("imu_gaps_longer_than_max_gap", []),
               "reinitialisations": {"count": int(sol.counters.get("imu_gap_restarts", 0)),
                                     "at_t": [e["t"] for e in events if e["kind"] == "imu_gap_restart"],
                                     "how": "the filter restarted after an IMU gap longer than max_gap_s: attitude "
                                            "and biases kept, heading unknown, covariance inflated"},
               "gnss_resets": {"count": int(sol.counters.get("gnss_resets", 0)),
                               "at_t": [e["t"] for e in events if e["kind"] == "gnss_reset"]},
               "events": events,
               "warnings": info.pop("warnings", []),
               "skipped": info.pop("skipped", {}), "fixes_after_end": sol.extra["fixes_after_end"],
               "wall_time_s": clock, "imu_samples": int(len(inp.imu)), "errors": stats,
               "update_kinds": {flt.UPDATE_KINDS[int(k)]: int(np.sum(sol.updates["kind"] == k))
                                for k in np.unique(sol.updates["kind"])},
               "solution_point": point,
               "outages": {"spec": spec.text() if spec is not None else None, "schedule": schedule.tolist(),
                           "gnss_first_t": inp.gnss_span[0], "gnss_last_t": inp.gnss_span[1],
                           "fixes_removed": int(fix_out.sum()),
                           "pseudoranges_removed": 0 if inp.pseudoranges is None else
                           int(len(inp.pseudoranges) - len(prs))},
               "scoring": scoring}
    if reference_system:
        summary["reference_system"] = reference_system
    if "heading_search" in sol.extra:
        summary["heading_search"] = sol.extra["heading_search"]
    if mode == "ins":
        summary["ins"] = {"aiding_until_t": free_from, "fixes_used": int(len(fixes)),
                          "how": "loose filter fed the fixes up to the one that completed the initialisation "
                                 "(heading known); zero-velocity and zero-rate updates off"}
    if smoothed is not None:
        summary["smoothed"] = smoothed[0]
    if info:
        summary["dataset"] = info
    (out / "run.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    return ReplayResult(out, mode, summary)


def solution_arrays(sol: flt.Solution) -> dict:
    """A solution's arrays as results.npz holds them (the forward and the smoothed one alike)."""
    sigma_ned, sigma_ypr = _nav_sigmas(sol)
    llh = sol.llh()
    c_en = evaluate.c_en(llh[:, 0], llh[:, 1])
    p_v_ned = np.swapaxes(c_en, -1, -2) @ sol.covariance[:, 3:6, 3:6] @ c_en
    a = dict(r_ecef=sol.r_ecef, v_ecef=sol.v_ecef, q_eb=sol.q_eb, llh=llh, ypr_deg=np.degrees(sol.ypr()),
             gyro_bias=sol.gyro_bias, accel_bias=sol.accel_bias, sigma=sol.sigma, sigma_ned_m=sigma_ned,
             sigma_ypr_deg=sigma_ypr, sigma_v_ned_mps=np.sqrt(np.diagonal(p_v_ned, axis1=1, axis2=2)))
    if sol.clock is not None:
        a["clock"] = sol.clock
    return a


def truth_errors(sol: flt.Solution, tr: evaluate.Truth) -> tuple[dict, dict]:
    """Errors against the simulator's truth: per-epoch arrays (NaN outside the truth's span) and
    their statistics from the first known heading on (none if a short or standing run never got there)."""
    inside = (sol.t >= tr.t[0]) & (sol.t <= tr.t[-1])
    err = evaluate.nav_errors(_subset(sol, inside), tr)
    ref = tr.at(sol.t[inside])
    llh_ref = flt._core.ecef_to_geodetic(ref.r_ecef)
    c_en = evaluate.c_en(llh_ref[:, 0], llh_ref[:, 1])
    dv_ned = np.einsum("nji,nj->ni", c_en, sol.v_ecef[inside] - ref.v_ecef)
    nees = evaluate.nees(err.e9, sol.covariance[inside][:, :9, :9])
    arrays = dict(err_ned_m=_fill(inside, err.r_ned), err_ypr_deg=_fill(inside, err.ypr_deg),
                  err_v_ned_mps=_fill(inside, dv_ned), nees9=_fill(inside, nees))
    hk = sol.heading_known[inside]
    if not hk.any():
        return arrays, {}
    h = np.hypot(err.r_ned[hk, 0], err.r_ned[hk, 1])
    return arrays, {"horizontal_rms_m": float(np.sqrt(np.mean(h ** 2))), "horizontal_max_m": float(h.max()),
                    "vertical_rms_m": float(np.sqrt(np.mean(err.r_ned[hk, 2] ** 2))),
                    "vertical_max_m": float(np.abs(err.r_ned[hk, 2]).max()),
                    "nees9_mean": float(nees[hk].mean()),
                    "inside_3_sigma": float(np.mean(np.abs(err.e9[hk]) <= 3 * sol.sigma[inside][hk, :9]))}


def reference_scores(t: np.ndarray, r_score: np.ndarray, ref: tuple, schedule: np.ndarray
                     ) -> tuple[dict, dict, np.ndarray]:
    """Errors against a reference (t, r_ecef, name) and the per-outage drift: arrays, the scoring
    summary, and which reference epochs were used."""
    sc = outages_mod.score(t, r_score, ref[0], ref[1], schedule)
    use, e = outages_mod.errors_ned(t, r_score, ref[0], ref[1])
    h = np.hypot(e[:, 0], e[:, 1])
    scoring = {"all": {"rms_h_m": float(np.sqrt(np.mean(h ** 2))) if len(h) else float("nan"),
                       "rms_v_m": float(np.sqrt(np.mean(e[:, 2] ** 2))) if len(h) else float("nan"),
                       "max_h_m": float(h.max()) if len(h) else float("nan")},
               **sc.summary()}
    arrays = dict(ref_err_ned_m=e, drift_t_s=sc.drift_t_s, drift_h_m=sc.drift_h_m, drift_v_m=sc.drift_v_m,
                  drift_outage=sc.drift_outage)
    return arrays, scoring, use


def _with_positions(sol: flt.Solution, r_ecef: np.ndarray) -> flt.Solution:
    import dataclasses
    return dataclasses.replace(sol, r_ecef=r_ecef)


def _fill(mask: np.ndarray, a: np.ndarray) -> np.ndarray:
    full = np.full((len(mask),) + a.shape[1:], np.nan)
    full[mask] = a
    return full


def _subset(sol: flt.Solution, m: np.ndarray) -> flt.Solution:
    return flt.Solution(sol.mode, sol.n_states, sol.t[m], sol.r_ecef[m], sol.v_ecef[m], sol.q_eb[m], sol.gyro_bias[m],
                        sol.accel_bias[m], sol.sigma[m], sol.standstill[m], sol.heading_known[m], sol.updates,
                        sol.counters)
