"""Scenarios are data: a TOML file of drive segments, obstructions, and the
device models' parameters. Unknown keys are errors that name the file and key.

Each segment ramps speed, heading and grade from their values at its start
to its targets with a quintic smoothstep (zero first and second derivative
at both ends), so acceleration and angular rate are continuous everywhere.

Two keys build long drives from short ones:

- ``base = "NAME"`` (a built-in scenario or a TOML path relative to this
  file) starts from that scenario: its segments and obstructions, and its
  ``[start]``, ``[imu]``, ``[gnss]``, ``[timing]`` tables, which this file's
  tables override key by key. A file with a base has no ``[[segment]]`` of
  its own.
- ``[[repeat]]`` with ``first``, ``last`` (segment labels) and ``count``
  drives the segments from ``first`` to ``last`` ``count`` times in a row;
  the obstructions inside that span come back with every pass, later ones
  move on. Copies are labelled ``LABEL #2``, ``LABEL #3``, ...

Roll: ``bank_deg`` ramps a segment's roll to a target like the grade (a banked
road, a tilted body); ``coordinated = true`` adds the bank of a coordinated
turn, atan(v yaw_rate cos(pitch) / g0), which is zero at the segment's ends.

A ``[track]`` table replaces the segments with a ride along a closed 3-D curve
(sim/track.py): ``points`` rows [north, east, down (m from the start point),
bank_deg, speed_kmh] splined periodically, ``laps``, ``rest_before_s`` and
``rest_after_s`` standing at the start point, ``ramp_s`` to start and stop; the
segments become "Initialisation", "Lap 1".."Lap N" and "Stop", and each
``[[track.cover]]`` (``points = [i, j]``, ``below_elevation_deg``,
``azimuth_deg``, ``flicker``) becomes an obstruction on every lap.

``[ride]`` rocks the body on its suspension (sim/ride.py: pitch and roll RMS, their band, growing
with speed); off unless its angles are set.

``[reference]`` sets the dual-antenna RTK reference written beside the session
(sim/reference.py; ``enabled = false`` writes none).

The IMU's ``rate_hz`` may be any positive integer: 64, 32, 16 and 8 Hz are
the BP3010's own rates; other rates keep its frame layout (LSBs scaled by
64 / rate, as the frame specification defines) and suit the robustness
benchmarks. ``timing.imu_baud`` must carry the frames (16 bytes of 10 bits
each per sample); ``with_imu_rate`` raises it to the lowest standard baud
that does.
"""

from __future__ import annotations

import copy
import tomllib
from dataclasses import dataclass, field, fields
from importlib import resources
from pathlib import Path

import numpy as np

from gpsins_logger import bp3010
from gpsins_logger.config import STANDARD_BAUDS

from .reference import ReferenceModel
from .ride import RideModel
from .track import Cover, Track, TrackSpec

LINE_BITS_PER_BYTE = 10  # 8N1


class ScenarioError(ValueError):
    pass


@dataclass
class Segment:
    label: str
    duration_s: float
    speed_mps: float | None = None  # target at the end; None keeps the current speed
    turn_deg: float = 0.0  # heading change over the segment, + to the right
    grade_deg: float | None = None  # target road grade (pitch), + uphill
    bank_deg: float | None = None  # target roll (banked road, body roll), + right side down
    coordinated: bool = False  # add the bank of a coordinated turn, atan(v yaw_rate cos(pitch) / g0)


@dataclass
class Obstruction:
    t0_s: float
    t1_s: float
    azimuth_deg: tuple[float, float]  # sector from, to (clockwise from north)
    below_elevation_deg: float  # satellites in the sector under this elevation are blocked
    flicker: float = 0.0  # forest: probability that a blocked satellite comes through in a period
    flicker_period_s: float = 4.0
    label: str = ""


@dataclass
class Start:
    gps_week: int = 1590
    gps_tow_s: float = 419400.0  # 2010-07-01 20:30 GPST
    lat_deg: float = 59.37
    lon_deg: float = 17.95
    height_m: float = 30.0
    heading_deg: float = 0.0


@dataclass
class ImuModel:
    rate_hz: int = 64
    seed_offset: int = 1
    # Turn-on bias: the calibrated values (report Tables 5.1, 5.5) plus a random residual of this size.
    gyro_bias_rad_per_s: tuple = (0.0003962, 0.0146681, 0.0195939)
    gyro_bias_residual_rad_per_s: float = 2e-3
    accel_bias_mps2: tuple = (0.2899, 0.2312, 0.1928)
    accel_bias_residual_mps2: float = 0.03
    gyro_scale_factor: tuple = (-0.0020, -0.0042, -0.0017)
    accel_scale_factor: tuple = (-4.7856e-4, -0.0014, -0.0031)
    gyro_misalignment_rad: float = 1e-3  # std of each off-diagonal term
    accel_misalignment_rad: float = 1e-3
    # Gyro g-sensitivity: std of each element of the 3x3 matrix G (rate error G f); 0 = none and no draw.
    gyro_g_sensitivity_rad_per_s_per_mps2: float = 0.0
    # Warm-up after power-on: each axis's bias moves by a step drawn with this std, as 1 - exp(-t / tau)
    # (the real walk's MEMS gyros: about 5e-4 rad/s between rests two minutes apart); 0 = none and no draw.
    gyro_warmup_rad_per_s: float = 0.0
    accel_warmup_mps2: float = 0.0
    warmup_tau_s: float = 120.0
    # Noise (report Tables 5.8, 5.9: Q is the white-noise N, B bias instability, K rate random walk).
    gyro_arw_rad_per_sqrt_s: tuple = (8.8e-4, 8.7e-4, 8.1e-4)
    gyro_bias_instability_rad_per_s: tuple = (4.7e-4, 4.7e-4, 3.6e-4)
    gyro_rrw_rad_per_s_sqrt_s: tuple = (1.8e-4, 1.9e-4, 0.0)
    accel_vrw_mps_per_sqrt_s: tuple = (78.4e-4, 61.0e-4, 69.7e-4)
    accel_bias_instability_mps2: tuple = (43.8e-4, 24.5e-4, 0.0)
    accel_rrw_mps2_per_sqrt_s: tuple = (23.2e-4, 9.8e-4, 13.4e-4)
    # Bias instability is a sum of Gauss-Markov processes with these time constants, weighted to
    # give a flat Allan deviation of 0.664 B between about the shortest and longest.
    bias_instability_tau_s: tuple = (3.0, 10.0, 30.0, 100.0, 300.0, 1000.0)
    terms: dict = field(default_factory=lambda: dict(
        turn_on_bias=True, scale_factor=True, misalignment=True, white_noise=True, bias_instability=True,
        rate_random_walk=True, quantisation=True))


CLOCK_MODELS = ("steered", "unsteered", "ms_jumps")


@dataclass
class GnssModel:
    nav_file: str = "brdc1820.10n"  # bundled name, or a path
    elevation_mask_deg: float = 5.0
    measurement_rate_hz: int = 10
    fix_rate_hz: int = 1
    reacquire_s: float = 2.0
    code_noise_m: float = 0.75  # at zenith; grows as 1/sin(elevation)^0.5
    multipath_m: float = 0.6  # at zenith; grows as 1/sin(elevation)
    multipath_tau_s: float = 20.0
    # Broadcast orbit and clock error along the line of sight (signal in space), per satellite: a
    # constant plus a term at the orbital period, each drawn with this sigma (about 0.8 m RMS, the
    # size measured for GPS broadcast ephemerides around 2010; the URA the satellites send, 2.4 m,
    # bounds it): 0.65 gives that. 0: the broadcast ephemeris is exact.
    sis_error_m: float = 0.65
    sis_period_s: float = 43082.0
    carrier_noise_cycles: float = 0.02
    iono_scale: float = 1.15  # true ionosphere = Klobuchar x scale x (1 + slow variation)
    iono_variation: float = 0.15
    iono_period_s: float = 900.0
    trop_wet_zenith_m: float = 0.18  # the standard-atmosphere model assumes about 0.1
    # steered: the receiver trims its oscillator towards zero drift; unsteered: a free-running TCXO
    # (5e-8 s/s); ms_jumps: free-running at clock_drift_s_per_s, the bias held within 0.5 ms by
    # whole-millisecond steps (what many receivers do instead of steering)
    clock: str = "steered"
    clock_bias_s: float = 2e-8
    clock_drift_s_per_s: float = 1e-9
    clock_phase_noise_s_per_sqrt_s: float = 2e-10
    clock_freq_noise_per_sqrt_s: float = 2e-11
    cn0_zenith_dbhz: float = 48.0
    leap_seconds: int = 15


@dataclass
class Timing:
    """How the logger's system-time stamps relate to the true first-byte times."""

    gps_latency_s: float = 0.0
    imu_latency_s: float = 0.0
    jitter_mean_s: float = 0.0003  # exponential, non-negative
    # Host load: the logger stalls (Poisson events, Pareto durations with shape 2.5, heavy-tailed);
    # a frame arriving during a stall is stamped when the stall ends. Both streams see the same stalls.
    load_stall_rate_hz: float = 0.0
    load_stall_mean_s: float = 0.15
    # The GPS port not read for this long from the start (the logger's GPS thread busy with the
    # receiver's set-up requests): its frames queue and are stamped when it is read.
    gps_setup_hold_s: float = 0.0
    imu_clock_ppm: float = 0.0
    imu_drop_probability: float = 0.0
    system_clock_offset_s: float = 0.25  # system clock minus true UTC at the start
    clock_step_at_s: float | None = None
    clock_step_s: float = 0.0
    gps_baud: int = 115200
    imu_baud: int = 38400


@dataclass
class Scenario:
    name: str
    segments: list[Segment]
    obstructions: list[Obstruction] = field(default_factory=list)
    start: Start = field(default_factory=Start)
    imu: ImuModel = field(default_factory=ImuModel)
    gnss: GnssModel = field(default_factory=GnssModel)
    timing: Timing = field(default_factory=Timing)
    description: str = ""
    source: str = ""
    track: Track | None = None  # a ride along a 3-D track instead of segment profiles
    reference: ReferenceModel = field(default_factory=ReferenceModel)  # the dual-antenna RTK reference
    ride: RideModel = field(default_factory=RideModel)  # the body's pitch and roll on its suspension

    @property
    def duration_s(self) -> float:
        return sum(s.duration_s for s in self.segments)

    def segment_times(self) -> list[tuple[str, float, float]]:
        out, t = [], 0.0
        for s in self.segments:
            out.append((s.label, t, t + s.duration_s))
            t += s.duration_s
        return out


def _build(cls, table: dict, where: str):
    names = {f.name: f for f in fields(cls)}
    unknown = set(table) - set(names)
    if unknown:
        raise ScenarioError(f"{where}: unknown key(s) {', '.join(sorted(unknown))} (known: {', '.join(names)})")
    kw = {}
    for k, v in table.items():
        kw[k] = tuple(v) if isinstance(v, list) else v
    try:
        return cls(**kw)
    except TypeError as e:
        raise ScenarioError(f"{where}: {e}") from None


TOP_KEYS = {"name", "description", "base", "start", "segment", "obstruction", "repeat", "imu", "gnss", "timing",
            "track", "reference", "ride"}
TABLE_KEYS = ("start", "imu", "gnss", "timing", "reference", "ride")


def _with_base(data: dict, source: str, here: Path | None, seen: tuple[str, ...]) -> tuple[dict, str]:
    """The file's data on top of its base's (recursively); segment sources are named for errors."""
    base = data["base"]
    if data.get("segment") or data.get("obstruction") or data.get("track"):
        raise ScenarioError(f"{source}: a scenario with a base takes its segments and obstructions from it; "
                            f"remove [[segment]], [[obstruction]] and [track] or the base")
    if not isinstance(base, str):
        raise ScenarioError(f"{source}: base must be a scenario name or a TOML path")
    path = Path(base)
    if path.suffix == ".toml" and not path.is_absolute() and here is not None:
        path = here / path
    bdata, bsource = _read(str(path) if path.suffix == ".toml" else base)
    if bsource in seen:
        raise ScenarioError(f"{source}: base cycle through {bsource}")
    if "base" in bdata:
        bdata, bsource = _with_base(bdata, bsource, _dir_of(bsource), seen + (bsource,))
    merged = dict(bdata)
    merged.pop("base", None)
    merged["name"] = data.get("name", _stem(source))
    if "description" in data:
        merged["description"] = data["description"]
    for k in TABLE_KEYS:
        table = dict(bdata.get(k, {}))
        for key, value in data.get(k, {}).items():
            if k == "imu" and key == "terms":
                value = {**table.get("terms", {}), **value}
            table[key] = value
        if table:
            merged[k] = table
    merged["repeat"] = list(bdata.get("repeat", [])) + list(data.get("repeat", []))
    return merged, f"{source} (base {bsource})"


def _repeat(segs: list[Segment], obs: list[Obstruction], spec: dict, where: str):
    """Segments first..last driven count times; the obstructions inside come back every pass."""
    unknown = set(spec) - {"first", "last", "count"}
    if unknown or not {"first", "last", "count"} <= set(spec):
        raise ScenarioError(f"{where}: needs exactly first, last and count")
    count = spec["count"]
    if not isinstance(count, int) or count < 1:
        raise ScenarioError(f"{where}: count must be an integer >= 1, got {count!r}")
    labels = [s.label for s in segs]
    idx = []
    for key in ("first", "last"):
        hits = [i for i, label in enumerate(labels) if label == spec[key]]
        if len(hits) != 1:
            raise ScenarioError(f"{where}: {key} = {spec[key]!r} names {len(hits)} segments (needs exactly one)")
        idx.append(hits[0])
    i0, i1 = idx
    if i1 < i0:
        raise ScenarioError(f"{where}: segment {spec['last']!r} comes before {spec['first']!r}")
    t0 = sum(s.duration_s for s in segs[:i0])
    span = sum(s.duration_s for s in segs[i0:i1 + 1])
    t1 = t0 + span
    block = segs[i0:i1 + 1]
    copies = [Segment(**{**s.__dict__, "label": f"{s.label} #{k + 1}"}) for k in range(1, count) for s in block]
    out_obs = []
    for j, o in enumerate(obs):
        if o.t1_s <= t0:
            out_obs.append(o)
        elif o.t0_s >= t1:
            out_obs.append(Obstruction(**{**o.__dict__, "t0_s": o.t0_s + (count - 1) * span,
                                          "t1_s": o.t1_s + (count - 1) * span}))
        elif o.t0_s >= t0 and o.t1_s <= t1:
            out_obs.extend(Obstruction(**{**o.__dict__, "t0_s": o.t0_s + k * span, "t1_s": o.t1_s + k * span})
                           for k in range(count))
        else:
            raise ScenarioError(f"{where}: obstruction {j + 1} ({o.t0_s:g}-{o.t1_s:g} s) straddles the repeated "
                                f"span {t0:g}-{t1:g} s")
    return segs[:i1 + 1] + copies + segs[i1 + 1:], out_obs


def check_imu_line(imu: ImuModel, timing: Timing, where: str = "<scenario>") -> None:
    """The IMU rate is a positive integer and the IMU's line carries its frames."""
    if isinstance(imu.rate_hz, bool) or not isinstance(imu.rate_hz, int) or imu.rate_hz <= 0:
        raise ScenarioError(f"{where}: [imu] rate_hz must be a positive integer, got {imu.rate_hz!r}")
    need = bp3010.FRAME_LEN * LINE_BITS_PER_BYTE * imu.rate_hz
    if timing.imu_baud < need:
        raise ScenarioError(f"{where}: [timing] imu_baud = {timing.imu_baud} cannot carry {imu.rate_hz} Hz frames "
                            f"({need} bit/s); use at least {line_baud(imu.rate_hz)}")


def line_baud(rate_hz: int) -> int:
    """The lowest standard baud that carries the IMU's frames at rate_hz."""
    need = bp3010.FRAME_LEN * LINE_BITS_PER_BYTE * rate_hz
    for b in STANDARD_BAUDS:
        if b >= need:
            return b
    raise ScenarioError(f"no standard baud carries {rate_hz} Hz IMU frames ({need} bit/s)")


def with_imu_rate(sc: Scenario, rate_hz: int) -> Scenario:
    """A copy of the scenario with the IMU at rate_hz (and its line's baud raised if it must be)."""
    out = copy.deepcopy(sc)
    out.imu.rate_hz = int(rate_hz)
    if out.timing.imu_baud < bp3010.FRAME_LEN * LINE_BITS_PER_BYTE * out.imu.rate_hz:
        out.timing.imu_baud = line_baud(out.imu.rate_hz)
    check_imu_line(out.imu, out.timing, f"scenario {sc.name}")
    return out


def first_seconds(sc: Scenario, seconds: float) -> Scenario:
    """A copy of the scenario cut to the segments that start within its first `seconds` (and the
    obstructions that begin before its new end): short runs of a long profile for tests."""
    out = copy.deepcopy(sc)
    keep, t = [], 0.0
    for seg in out.segments:
        if t >= seconds:
            break
        keep.append(seg)
        t += seg.duration_s
    out.segments = keep
    out.obstructions = [o for o in out.obstructions if o.t0_s < t]
    return out


def parse(data: dict, source: str = "<scenario>", here: Path | None = None) -> Scenario:
    """A scenario from its TOML data; `here` is the directory relative base paths start from."""
    unknown = set(data) - TOP_KEYS
    if unknown:
        raise ScenarioError(f"{source}: unknown key(s) {', '.join(sorted(unknown))}")
    if "base" in data:
        data, source = _with_base(data, source, here, (source,))
    track, track_obs = None, []
    if "track" in data:
        if data.get("segment"):
            raise ScenarioError(f"{source}: a scenario with a [track] has no [[segment]] (the laps are its segments)")
        track, segs, track_obs = _track(data["track"], source)
    else:
        segs = [_build(Segment, s, f"{source}: segment {i + 1}") for i, s in enumerate(data.get("segment", []))]
    if not segs:
        raise ScenarioError(f"{source}: no [[segment]]")
    for i, s in enumerate(segs):
        if not s.duration_s > 0:
            raise ScenarioError(f"{source}: segment {i + 1} ({s.label}): duration_s must be > 0")
    times = {label: (t0, t1) for label, t0, t1 in Scenario("", segs).segment_times()}
    obs = list(track_obs)
    for i, o in enumerate(data.get("obstruction", [])):
        o = dict(o)
        if "segment" in o:
            label = o.pop("segment")
            if label not in times:
                raise ScenarioError(f"{source}: obstruction {i + 1}: no segment labelled {label!r}")
            o.setdefault("t0_s", times[label][0])
            o.setdefault("t1_s", times[label][1])
        obs.append(_build(Obstruction, o, f"{source}: obstruction {i + 1}"))
    imu_table = dict(data.get("imu", {}))
    terms = imu_table.pop("terms", {})
    imu = _build(ImuModel, imu_table, f"{source}: [imu]")
    bad = set(terms) - set(imu.terms)
    if bad:
        raise ScenarioError(f"{source}: [imu.terms]: unknown term(s) {', '.join(sorted(bad))}")
    imu.terms.update(terms)
    timing = _build(Timing, data.get("timing", {}), f"{source}: [timing]")
    check_imu_line(imu, timing, source)
    repeats = data.get("repeat", [])
    for i, spec in enumerate([repeats] if isinstance(repeats, dict) else repeats):
        if not isinstance(spec, dict):
            raise ScenarioError(f"{source}: repeat {i + 1}: must be a table")
        segs, obs = _repeat(segs, obs, spec, f"{source}: repeat {i + 1}")  # in order: a later one sees the copies
    gnss = _build(GnssModel, data.get("gnss", {}), f"{source}: [gnss]")
    if gnss.clock not in CLOCK_MODELS:
        raise ScenarioError(f"{source}: [gnss] clock = {gnss.clock!r}; one of {', '.join(CLOCK_MODELS)}")
    return Scenario(name=data.get("name", _stem(source)), description=data.get("description", ""),
                    segments=segs, obstructions=obs, start=_build(Start, data.get("start", {}), f"{source}: [start]"),
                    imu=imu, gnss=gnss,
                    timing=timing, source=source, track=track,
                    reference=_build(ReferenceModel, data.get("reference", {}), f"{source}: [reference]"),
                    ride=_ride(data.get("ride", {}), source))


def _ride(table: dict, source: str) -> RideModel:
    m = _build(RideModel, table, f"{source}: [ride]")
    lo, hi = (float(x) for x in m.band_hz) if len(m.band_hz) == 2 else (0.0, -1.0)
    if not (0.0 < lo <= hi and m.pitch_deg >= 0.0 and m.roll_deg >= 0.0 and m.reference_speed_mps > 0.0
            and m.components >= 1):
        raise ScenarioError(f"{source}: [ride]: band_hz = [low, high] with 0 < low <= high, angles >= 0, "
                            f"reference_speed_mps > 0, components >= 1")
    return m


def _track(table: dict, source: str) -> tuple[Track, list[Segment], list[Obstruction]]:
    """The track, its segments (rest, laps, rest) and the covers' obstructions on every lap."""
    where = f"{source}: [track]"
    table = dict(table)
    covers = [_build(Cover, c, f"{where} cover {i + 1}") for i, c in enumerate(table.pop("cover", []))]
    spec = _build(TrackSpec, table, where)
    spec.points = [list(p) for p in spec.points]
    spec.cover = covers
    try:
        tr = Track(spec, where)
    except ValueError as e:
        raise ScenarioError(str(e)) from None
    rest0 = float(spec.rest_before_s)
    segs = [Segment("Initialisation", rest0, speed_mps=0.0)] if rest0 > 0 else []
    segs += [Segment(f"Lap {k + 1}", float(tr.lap_times[k + 1] - tr.lap_times[k])) for k in range(spec.laps)]
    if spec.rest_after_s > 0:
        segs.append(Segment("Stop", float(spec.rest_after_s)))
    # Cover stretches by point index, on every lap: times from the ride's u(t).
    tau = np.linspace(0.0, tr.ride_s, int(tr.ride_s * 200) + 2)
    u = tr.u_of(tau)[0]
    obs = []
    n_pts = len(spec.points)
    for i, c in enumerate(covers):
        a, b = c.points
        if not (0 <= a < n_pts and 0 <= b < n_pts):
            raise ScenarioError(f"{where} cover {i + 1}: points must be indices 0..{n_pts - 1}")
        ua, ub = tr.knots[a], tr.knots[b] if b > a else tr.knots[b] + tr.period
        for lap in range(spec.laps):
            t_in = np.interp([lap * tr.period + ua, lap * tr.period + ub], u, tau, right=np.nan)
            if not np.all(np.isfinite(t_in)):
                continue
            obs.append(Obstruction(rest0 + t_in[0], rest0 + t_in[1], tuple(c.azimuth_deg), c.below_elevation_deg,
                                   c.flicker, c.flicker_period_s, f"{c.label} lap {lap + 1}"))
    return tr, segs, obs


def builtin_names() -> list[str]:
    return sorted(p.name[:-5] for p in resources.files(__package__).joinpath("scenarios").iterdir()
                  if p.name.endswith(".toml"))


def _stem(source: str) -> str:
    return source[len("scenario "):] if source.startswith("scenario ") else Path(source).stem


def _dir_of(source: str) -> Path | None:
    return None if source.startswith("scenario ") else Path(source).parent


def _read(name_or_path: str | Path) -> tuple[dict, str]:
    """The TOML data of a built-in scenario or a file, and its name for messages."""
    p = Path(name_or_path)
    if p.suffix != ".toml" and str(name_or_path) in builtin_names():
        text = resources.files(__package__).joinpath("scenarios", f"{name_or_path}.toml").read_text("utf-8")
        source = f"scenario {name_or_path}"
    else:
        try:
            text = p.read_text(encoding="utf-8")
        except OSError as e:
            raise ScenarioError(f"{p}: cannot read ({e.strerror}); built-in scenarios: "
                                f"{', '.join(builtin_names())}") from None
        source = str(p)
    try:
        return tomllib.loads(text), source
    except tomllib.TOMLDecodeError as e:
        raise ScenarioError(f"{source}: {e}") from None


def load(name_or_path: str | Path) -> Scenario:
    """A built-in scenario by name (`default`, ...) or a TOML file."""
    data, source = _read(name_or_path)
    return parse(data, source, _dir_of(source))
