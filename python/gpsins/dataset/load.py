"""Data sets that are not logger sessions: a TOML file that says where another recording's
files are and how to read them, loaded into plain decoded arrays (``load(path) -> Dataset``).

The keys of the data-set format (``dataset.md`` of the project's specifications) are the
interface::

    name = "walk_0827"
    [imu]      file, format = "csv" | "kf-gins", columns, time, week, accel_unit, gyro_unit,
               time_offset_s, imu_to_body
    [gnss]     file, format = "rtklib-pos" | "kf-gins" | "rinex" | "ubx", nav, antenna_m
    [vehicle]  kind = "none" | "car"
    [filter]   the same keys as a --config file; presets allowed

Extensions (all optional):

- ``[imu] imu_to_body_ypr_deg = [yaw, pitch, roll]``: the IMU axes as the body axes rotated
  by yaw, pitch, roll (instead of the matrix ``imu_to_body``; v_body = Rz Ry Rx v_imu).
- ``[imu] delimiter``, ``skip_rows``: the table's separator and header lines (guessed when absent).
- ``[imu] time = "gps_abs"`` (GPS seconds since 1980-01-06) and ``"utc_unix"`` (Unix time in
  UTC: leap seconds added).
- ``[imu] time = "rtklib_tag"``, ``tag = "FILE.tag"``, ``counter_hz``: a raw stream logged by RTKLIB
  (str2str, rtknavi) with its time tags; ``columns`` name a ``counter`` (the sensor's own sample counter,
  ``counter_bits`` 32 unless given) instead of ``t``. Each sample's time is its counter mapped onto the
  tags' arrival times along their lower envelope (``timing.envelope.counter_times``); the first line and an
  unterminated last one are not used (the logger starts and stops mid-line).
- ``[gnss] week``: the GPS week of a kf-gins GNSS file (default: ``[imu] week``).
- ``[gnss] geoid_height_m``, ``[scoring] reference_geoid_height_m``: for .pos (and kf-gins)
  heights above the geoid, the geoid's height above the ellipsoid (added to them).
- ``[gnss] systems = ["gps", "galileo"]`` (the default): the systems a UBX stream's pseudoranges and
  ephemerides are taken from (GPS L1 C/A, Galileo E1).
- ``[gnss] nav`` may be a list of RINEX navigation files; with ``format = "ubx"`` they add to
  the ephemerides decoded from the stream's SFRBX.
- ``[gnss.sigma_floor_m]`` ``fix``, ``float``, ``sbas``, ``dgps``, ``single``, ``ppp``, ``unknown`` =
  ``[horizontal, vertical]``: the smallest 1-sigma a fix of that quality is given (``SIGMA_FLOOR_M``);
  ``[gnss.sigma_default_m]`` the same keys: the sigma of a fix whose file states none
  (``SIGMA_DEFAULT_M``); ``[gnss] velocity_sigma_floor_mps``.
- ``[gnss] velocity_lag_s``: how long before its fix's time a fix velocity applies (seconds), or
  ``"measured"`` (the default): from the fixes themselves (``velocity_lag``; a receiver that reports the mean velocity
  over the epoch just ended gives half an epoch). The filter's ``fix_velocity_lag_s``.
- ``[gnss] antenna_sigma_m``: how well ``antenna_m`` is known, 1-sigma per body axis (one number or
  three; default 0, exact). Where it is above 0, replay fits the lever arm to the recording
  (``gpsins.nav.lever_arm``) with the stated one as its prior. The filter's ``lever_arm_sigma_m``.
- ``[gnss] ionosphere = "dual-frequency"`` (rinex, ubx; default ``"broadcast"``: Klobuchar when the
  navigation data has it): each L1 range less the ionospheric delay its second code measures (GPS L2,
  Galileo E5a; ``ionosphere.py``), averaged along each satellite's track over ``ionosphere_smoothing_s``
  (default 60); ranges without a second code are dropped and the filter leaves Klobuchar out.
- ``[scoring] reference = "FILE.pos"``, ``reference_q = [1]`` (the Q values that count),
  ``outages = "FIRST:LENGTH:PERIOD[:END]"``: defaults for ``--reference`` and ``--outages``.

File names are relative to the data-set file. Every time is GPS seconds since the GPS epoch
(``t_abs``); the IMU's are shifted by ``time_offset_s``; its increments are in body axes
(``imu_to_body`` applied).
"""

from __future__ import annotations

import tomllib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..timing import envelope
from ..gnss import ionosphere as ionosphere_mod
from ..evaluate import outages as outages_mod
from ..formats import imu_csv, kfgins, rinex, rtklib_pos, rtklib_tag, ubx
from ..formats.common import Fixes, Navigation, Pseudoranges, ReaderError
from ..formats.imu_csv import ImuData
from .fixes import SIGMA_FLOOR_M, VELOCITY_SIGMA_FLOOR_MPS


IMU_FORMATS = ("csv", "kf-gins")
GNSS_FORMATS = ("rtklib-pos", "kf-gins", "rinex", "ubx")
IONOSPHERE_MODELS = ("broadcast", "dual-frequency")
VEHICLE_KINDS = ("none", "car")
_KNOWN = {
    "": {"name", "imu", "gnss", "vehicle", "filter", "scoring", "description"},
    "imu": {"file", "format", "columns", "time", "week", "accel_unit", "gyro_unit", "time_offset_s", "imu_to_body",
            "imu_to_body_ypr_deg", "delimiter", "skip_rows", "tag", "counter_hz", "counter_bits"},
    "gnss": {"file", "format", "nav", "antenna_m", "antenna_sigma_m", "week", "geoid_height_m", "sigma_floor_m",
             "sigma_default_m", "velocity_sigma_floor_mps", "velocity_lag_s", "systems", "ionosphere",
             "ionosphere_smoothing_s"},
    "vehicle": {"kind"},
    "scoring": {"reference", "reference_q", "reference_geoid_height_m", "outages"},
}

# What a data set's IMU is taken to be when its [filter] table does not say: a factory-calibrated
# consumer MEMS unit, not the preset's BP3010 (whose bench calibration and turntable misalignment
# belong to that one unit). Its raw samples get no calibration; its turn-on bias residuals are
# datasheet-sized 1-sigma priors (Bosch BMI088: gyro zero-rate offset +-1 deg/s, accelerometer
# zero-g offset +-20 mg, taken here as about 2 sigma and 1 sigma); the triad's misalignment is not
# carried as attitude noise (a datasheet's cross-axis figure is a bound for the whole product line,
# and carried as noise at 5e-3 rad it would swamp a good unit's 3e-4 rad/s of rate noise; the
# recording's noise fit, gpsins.nav.noise_from_data, takes up what remains).
GENERIC_MEMS = {
    "gyro_bias_cal_rad_per_s": [0.0, 0.0, 0.0], "accel_bias_cal_mps2": [0.0, 0.0, 0.0],
    "gyro_scale_factor_cal": [0.0, 0.0, 0.0], "accel_scale_factor_cal": [0.0, 0.0, 0.0],
    "gyro_bias_residual_rad_per_s": 8.7e-3, "accel_bias_residual_mps2": 0.2,
    "gyro_misalignment_sigma_rad": 0.0,
}
# Fix qualities whose errors are centimetres to decimetres, correlated over seconds (carrier multipath, a
# float ambiguity settling): their stated sigmas (with SIGMA_FLOOR_M) are the whole model, and the preset's
# fix-error states, sized per unit of DOP for a standalone receiver's metres, do not apply.
CARRIER_QUALITIES = (1, 2, 6)
STANDALONE_FIX_MODEL_OFF = {"fix_error_gm_sigma_m": [0.0, 0.0, 0.0], "fix_error_fast_sigma_m": [0.0, 0.0, 0.0]}


class DatasetError(ReaderError):
    pass


@dataclass
class Dataset:
    name: str
    path: Path
    imu: ImuData  # increments in body axes, times with the offset applied
    imu_to_body: np.ndarray  # (3, 3) v_body = M v_imu
    imu_time_offset_s: float
    antenna_m: np.ndarray  # (3,) antenna phase centre relative to the IMU, body axes
    gnss_format: str
    fixes: Fixes | None = None  # rtklib-pos, kf-gins, ubx (NAV-PVT)
    pseudoranges: Pseudoranges | None = None  # rinex, ubx: GPS L1 C/A
    navigation: Navigation | None = None  # rinex, ubx: ephemerides and Klobuchar
    vehicle_kind: str = "none"
    filter_table: dict = field(default_factory=dict)  # the raw [filter] table
    reference: Fixes | None = None  # [scoring] reference, only the epochs whose Q counts
    outages: outages_mod.OutageSpec | None = None  # [scoring] outages
    skipped: Counter = field(default_factory=Counter)  # what the readers left out, and why
    notes: list[str] = field(default_factory=list)  # one line per damaged input
    sigma_floor_m: dict = field(default_factory=dict)  # [gnss.sigma_floor_m]: quality name -> (h, v)
    sigma_default_m: dict = field(default_factory=dict)  # [gnss.sigma_default_m]
    velocity_sigma_floor_mps: float = VELOCITY_SIGMA_FLOOR_MPS
    velocity_lag_s: float | str = "measured"  # [gnss] velocity_lag_s: seconds, or "measured" (the default)
    antenna_sigma_m: np.ndarray = field(default_factory=lambda: np.zeros(3))  # [gnss] antenna_sigma_m, per axis
    ionosphere: str = "broadcast"  # [gnss] ionosphere: "broadcast" (Klobuchar) or "dual-frequency" (ranges corrected)

    def gnss_span(self) -> tuple[float, float]:
        """First and last GNSS epoch (fixes or pseudoranges): the origin of the outage schedule."""
        t = self.fixes.t_abs if self.fixes is not None and len(self.fixes) else \
            self.pseudoranges.t_abs if self.pseudoranges is not None and len(self.pseudoranges) else None
        if t is None:
            raise DatasetError(self.path, "no GNSS epochs")
        return float(t[0]), float(t[-1])

    def outage_schedule(self, spec: str | outages_mod.OutageSpec | None = None) -> np.ndarray:
        """(k, 2) [start, end) GPS times of the outages (``spec`` or the data set's own; none: empty)."""
        spec = spec if spec is not None else self.outages
        if spec is None:
            return np.zeros((0, 2))
        return outages_mod.schedule(spec, *self.gnss_span())

    def filter_config(self, overrides: dict | None = None) -> dict:
        """The [filter] table completed from its preset, as ``gpsins.nav.config`` checks it."""
        from ..nav import config as nav_config
        return nav_config.load_config(dict(self.filter_table) or None, overrides)


def _table(doc: dict, name: str, path: Path) -> dict:
    t = doc.get(name, {})
    if not isinstance(t, dict):
        raise DatasetError(path, f"[{name}] must be a table", field=name)
    unknown = sorted(set(t) - _KNOWN[name])
    if unknown:
        raise DatasetError(path, f"unknown key(s) {', '.join(unknown)}", field=f"[{name}]")
    return t


def _matrix(value, path, key) -> np.ndarray:
    try:
        m = np.array(value, float)
    except (TypeError, ValueError):
        m = np.zeros(0)
    if m.shape != (3, 3):
        raise DatasetError(path, "must be a 3x3 matrix (rows)", field=key)
    if not np.allclose(m @ m.T, np.eye(3), atol=1e-6) or np.linalg.det(m) < 0:
        raise DatasetError(path, "is not a rotation (orthonormal, determinant +1)", field=key)
    return m


def ypr_to_matrix(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """Rz(yaw) Ry(pitch) Rx(roll): from axes rotated by yaw, pitch, roll back to the original axes."""
    y, p, r = np.radians([yaw_deg, pitch_deg, roll_deg])
    rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    return rz @ ry @ rx


def _vector(value, path, key) -> np.ndarray:
    try:
        v = np.array(value, float)
    except (TypeError, ValueError):
        v = np.zeros(0)
    if v.shape != (3,) or not np.isfinite(v).all():
        raise DatasetError(path, "must be three numbers", field=key)
    return v


def _file(base: Path, value, path, key) -> Path:
    if not isinstance(value, str) or not value:
        raise DatasetError(path, "needs a file name", field=key)
    f = (base / value)
    if not f.is_file():
        raise DatasetError(path, f"{value}: no such file (relative to the data-set file)", field=key)
    return f


def _positive_number(value) -> bool:
    """A TOML number (not a boolean) above zero."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and value > 0


def _read_tagged_imu(t: dict, f: Path, base: Path, path: Path) -> ImuData:
    """``time = "rtklib_tag"``: a raw stream logged with RTKLIB's time tags; the times are the sensor's counter
    (``counter_hz``) mapped onto the tags' arrival times (``timing.envelope.counter_times``)."""
    if "tag" not in t:
        raise DatasetError(path, 'time = "rtklib_tag" needs `tag = "FILE.tag"`', field="[imu] tag")
    hz = t.get("counter_hz")
    if not _positive_number(hz):
        raise DatasetError(path, "the counter's ticks per second (e.g. 1000 for milliseconds)",
                           field="[imu] counter_hz")
    accel_unit, gyro_unit = t.get("accel_unit", "m/s^2"), t.get("gyro_unit", "rad/s")
    rows = imu_csv.read_counter_rows(f, t["columns"], accel_unit, gyro_unit, t.get("delimiter"),
                                     int(t.get("counter_bits", 32)))
    tags = rtklib_tag.read(_file(base, t["tag"], path, "[imu] tag"))
    arrival = tags.arrival_t_abs(tags.stream_offsets(rows.end_offset, rows.line_no, rows.file_bytes,
                                                     rows.newlines))
    times, fit = envelope.counter_times(rows.counter / float(hz), arrival)
    imu = imu_csv.from_samples(times, rows.acc, rows.gyr, accel_unit, gyro_unit, f.name, rows.skipped)
    imu.alignment = {"tag": tags.source, **fit}
    return imu


def _rotated_in_place(x: np.ndarray, m: np.ndarray, block: int = 1 << 16) -> np.ndarray:
    """x (n, 3) turned by m row by row (x m^T), overwriting x."""
    x = np.ascontiguousarray(x, dtype=float)
    for a in range(0, len(x), block):
        x[a:a + block] = x[a:a + block] @ m.T
    return x


def _read_imu(t: dict, base: Path, path: Path) -> ImuData:
    fmt = t.get("format", "csv")
    f = _file(base, t.get("file"), path, "[imu] file")
    week = t.get("week")
    if fmt == "csv":
        if "columns" not in t:
            raise DatasetError(path, "a csv IMU needs `columns`", field="[imu] columns")
        if t.get("time") == "rtklib_tag":
            return _read_tagged_imu(t, f, base, path)
        return imu_csv.read(f, t["columns"], t.get("time", "gpst_unix"), t.get("accel_unit", "m/s^2"),
                            t.get("gyro_unit", "rad/s"), week, t.get("delimiter"), t.get("skip_rows"))
    if fmt == "kf-gins":
        if week is None:
            raise DatasetError(path, "a kf-gins IMU file has seconds of week: give `week = N`", field="[imu] week")
        return kfgins.read_imu(f, int(week))
    raise DatasetError(path, f"unknown format {fmt!r} ({', '.join(IMU_FORMATS)})", field="[imu] format")


def _systems(tg: dict, path: Path) -> list[str]:
    systems = tg.get("systems", list(ubx.SYSTEMS))
    if isinstance(systems, str):
        systems = [systems]
    bad = [x for x in systems if x not in ubx.SYSTEMS]
    if bad or not systems:
        raise DatasetError(path, f"unknown system(s) {bad} (of {', '.join(ubx.SYSTEMS)})", field="[gnss] systems")
    return list(systems)


def _nav_files(t: dict, base: Path, path: Path) -> list[Path]:
    nav = t.get("nav", [])
    return [_file(base, n, path, "[gnss] nav") for n in ([nav] if isinstance(nav, str) else nav)]


def _merge_nav(navs: list[Navigation]) -> Navigation:
    out = Navigation([])
    for n in navs:
        out.ephemerides += n.ephemerides
        if n.alpha and not out.alpha:
            out.alpha, out.beta = n.alpha, n.beta
        out.leap_s = out.leap_s if out.leap_s is not None else n.leap_s
        out.skipped.update(n.skipped)
    return out


def load(path: str | Path) -> Dataset:
    """Read a data-set TOML and every file it names."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise DatasetError(path, e.strerror or str(e)) from None
    except tomllib.TOMLDecodeError as e:
        raise DatasetError(path, str(e)) from None
    unknown = sorted(set(doc) - _KNOWN[""])
    if unknown:
        raise DatasetError(path, f"unknown key(s) {', '.join(unknown)}")
    base = path.parent
    ti, tg, tv, ts = (_table(doc, k, path) for k in ("imu", "gnss", "vehicle", "scoring"))
    if not ti:
        raise DatasetError(path, "no [imu] table", field="[imu]")
    if not tg:
        raise DatasetError(path, "no [gnss] table", field="[gnss]")
    kind = tv.get("kind", "none")
    if kind not in VEHICLE_KINDS:
        raise DatasetError(path, f"unknown kind {kind!r} ({', '.join(VEHICLE_KINDS)})", field="[vehicle] kind")
    ft = doc.get("filter", {})
    if not isinstance(ft, dict):
        raise DatasetError(path, "[filter] must be a table", field="[filter]")
    spec = None
    if "outages" in ts:
        try:
            spec = outages_mod.parse(ts["outages"])
        except outages_mod.OutageError as e:
            raise DatasetError(path, str(e), field="[scoring] outages") from None

    if "imu_to_body" in ti and "imu_to_body_ypr_deg" in ti:
        raise DatasetError(path, "give imu_to_body or imu_to_body_ypr_deg, not both", field="[imu]")
    if "imu_to_body_ypr_deg" in ti:
        m = ypr_to_matrix(*_vector(ti["imu_to_body_ypr_deg"], path, "[imu] imu_to_body_ypr_deg"))
    else:
        m = _matrix(ti.get("imu_to_body", np.eye(3).tolist()), path, "[imu] imu_to_body")
    offset = float(ti.get("time_offset_s", 0.0))
    raw = _read_imu(ti, base, path)
    # In place, block by block: the reader's arrays are this load's own, and an hour at 200 Hz is 41 MB.
    raw.t_abs += offset
    imu = ImuData(raw.t_abs, _rotated_in_place(raw.dtheta_rad, m), _rotated_in_place(raw.dv_mps, m), raw.source,
                  raw.skipped, alignment=raw.alignment, covers_gaps=raw.covers_gaps)
    skipped = Counter(raw.skipped)

    fmt = tg.get("format")
    if fmt not in GNSS_FORMATS:
        raise DatasetError(path, f"unknown format {fmt!r} ({', '.join(GNSS_FORMATS)})", field="[gnss] format")
    gfile = _file(base, tg.get("file"), path, "[gnss] file")
    ds = Dataset(str(doc.get("name", path.stem)), path, imu, m, offset,
                 _vector(tg.get("antenna_m", [0.0, 0.0, 0.0]), path, "[gnss] antenna_m"), fmt)
    ds.skipped = skipped
    if imu.alignment:
        a = imu.alignment
        late = a["arrival_above_envelope_ms"]
        ds.notes.append(f"{imu.source}: times from {a['tag']}: the counter runs {a['counter_rate_ppm']:+.1f} ppm "
                        f"against the logger's clock; arrival above the lower envelope median {late['median']:.1f} "
                        f"ms, 95 % {late['p95']:.1f} ms, worst {late['max']:.1f} ms")
    navs = [rinex.read_nav(n) for n in _nav_files(tg, base, path)]
    second = None  # the second frequency's ranges, read only if asked for
    if fmt == "rtklib-pos":
        ds.fixes = rtklib_pos.read(gfile, tg.get("geoid_height_m"))
    elif fmt == "kf-gins":
        week = tg.get("week", ti.get("week"))
        if week is None:
            raise DatasetError(path, "a kf-gins GNSS file has seconds of week: give `week = N`",
                               field="[gnss] week")
        ds.fixes = kfgins.read_gnss(gfile, int(week), float(tg.get("geoid_height_m", 0.0)))
    elif fmt == "rinex":
        if not navs:
            raise DatasetError(path, "a RINEX observation file needs `nav = \"FILE\"`", field="[gnss] nav")
        obs = rinex.read_obs(gfile)
        skipped.update(obs.skipped)
        ds.pseudoranges, second = obs.gps_l1(), obs.gps_l2
        ds.navigation = _merge_nav(navs)
    else:
        systems = _systems(tg, path)
        u = ubx.read(gfile)
        pr = u.pseudoranges
        ds.fixes, ds.pseudoranges = u.fixes, pr.select(np.isin(ubx.system_of(pr.prn), systems))
        second = u.second_frequency
        nav = u.navigation
        nav.ephemerides = [e for e in nav.ephemerides if ubx.system_of(e.prn) in systems]
        ds.navigation = _merge_nav([nav] + navs)
        for k, v in u.subframes.items():
            if "dropped" in k or "inconsistent" in k:
                skipped[f"ubx: {k}"] = v
        ids = nav.prns()
        ds.notes.append(f"{gfile.name}: {len(nav.ephemerides)} ephemerides from SFRBX "
                        f"({', '.join(ubx.sat_name(i) for i in ids) or 'none'})")
        if u.damage:
            skipped["ubx: damaged stretches"] = len(u.damage)
            ds.notes.append(u.damage_summary())
        dropped = len(u.pvt) - len(u.fixes)
        if dropped:
            skipped["ubx: NAV-PVT without a valid fix"] = dropped

    # What the GNSS readers left out (non-finite rows, cut-short lines, unusable ephemerides) counts
    # beside the IMU's.
    for part in (ds.fixes, ds.pseudoranges, ds.navigation):
        skipped.update(getattr(part, "skipped", None) or {})
    _ionosphere(ds, tg, second, path, skipped)
    ds.vehicle_kind, ds.filter_table, ds.outages = kind, ft, spec
    ds.sigma_floor_m = _quality_table(tg, "sigma_floor_m", path)
    ds.sigma_default_m = _quality_table(tg, "sigma_default_m", path)
    ds.velocity_sigma_floor_mps = float(tg.get("velocity_sigma_floor_mps", VELOCITY_SIGMA_FLOOR_MPS))
    if not ds.velocity_sigma_floor_mps > 0:
        raise DatasetError(path, "must be positive", field="[gnss] velocity_sigma_floor_mps")
    lag = tg.get("velocity_lag_s", "measured")
    if lag != "measured" and not (isinstance(lag, (int, float)) and not isinstance(lag, bool) and 0.0 <= lag < 10.0):
        raise DatasetError(path, 'seconds (0 to 10) or "measured"', field="[gnss] velocity_lag_s")
    ds.velocity_lag_s = lag if lag == "measured" else float(lag)
    sigma = tg.get("antenna_sigma_m", 0.0)
    sigma = np.full(3, sigma, float) if isinstance(sigma, (int, float)) and not isinstance(sigma, bool) else sigma
    ds.antenna_sigma_m = _vector(sigma, path, "[gnss] antenna_sigma_m")
    if (ds.antenna_sigma_m < 0).any() or (ds.antenna_sigma_m > 10.0).any():
        raise DatasetError(path, "1-sigma metres per axis, 0 to 10", field="[gnss] antenna_sigma_m")

    if "reference" in ts:
        ds.reference = load_reference(_file(base, ts["reference"], path, "[scoring] reference"),
                                      ts.get("reference_q", [1]), ts.get("reference_geoid_height_m"))
    return ds


def _ionosphere(ds: Dataset, tg: dict, second, path: Path, skipped: Counter) -> None:
    """``[gnss] ionosphere = "dual-frequency"``: the L1 ranges less the delay their second frequency measures
    (``ionosphere.corrected``, smoothed over ``ionosphere_smoothing_s``); ranges without one are dropped."""
    ds.ionosphere = tg.get("ionosphere", "broadcast")
    if ds.ionosphere not in IONOSPHERE_MODELS:
        raise DatasetError(path, f"unknown model {ds.ionosphere!r} ({', '.join(IONOSPHERE_MODELS)})",
                           field="[gnss] ionosphere")
    smoothing = tg.get("ionosphere_smoothing_s", ionosphere_mod.SMOOTHING_S)
    if not _positive_number(smoothing):
        raise DatasetError(path, "must be positive seconds", field="[gnss] ionosphere_smoothing_s")
    if ds.ionosphere == "broadcast":
        return
    if second is None:
        raise DatasetError(path, "only pseudoranges (rinex, ubx) have an ionosphere to correct",
                           field="[gnss] ionosphere")
    l2 = second()
    if not len(l2):
        raise DatasetError(path, "dual-frequency: the file has no second frequency (GPS L2, Galileo E5a)",
                           field="[gnss] ionosphere")
    n = len(ds.pseudoranges)
    ds.pseudoranges, dropped = ionosphere_mod.corrected(ds.pseudoranges, l2, ds.navigation, float(smoothing))
    skipped.update(dropped)
    ds.notes.append(f"dual-frequency ionosphere: {len(ds.pseudoranges)} of {n} L1 ranges have a second "
                    f"frequency in their epoch and are corrected, the rest dropped")


def _quality_table(tg: dict, key: str, path: Path) -> dict:
    t = tg.get(key, {})
    where = f"[gnss.{key}]"
    if not isinstance(t, dict):
        raise DatasetError(path, "must be a table (quality = [horizontal, vertical])", field=where)
    out = {}
    for name, value in t.items():
        if name not in SIGMA_FLOOR_M:
            raise DatasetError(path, f"unknown quality {name!r} ({', '.join(SIGMA_FLOOR_M)})", field=where)
        try:
            hv = tuple(float(x) for x in value)
        except (TypeError, ValueError):
            hv = ()
        if len(hv) != 2 or not all(np.isfinite(hv)) or min(hv) <= 0:
            raise DatasetError(path, "must be two positive numbers [horizontal, vertical] (m)",
                               field=f"{where} {name}")
        out[name] = hv
    return out


def load_reference(path: str | Path, q=(1,), geoid_height_m: float | None = None) -> Fixes:
    """A reference trajectory from an RTKLIB .pos: only the epochs whose Q is in ``q`` (default: fixed)."""
    f = rtklib_pos.read(path, geoid_height_m)
    return f.select(np.isin(f.q, list(q)))
