"""The simulator plays the IMU laboratory (the FOI report, chapter 5): a BP3010 with
known errors is recorded in the up-down positions of each accelerometer axis,
on a rate table at several rates about each axis, and standing still for a long
drift test, each as a logger session directory, plus the lab plan that names
them (what `gpsins lab` reads).

The whole day is one powered-on timeline: the unit's bias wanders on through
the handling between sessions (which is simulated but not recorded), so a
calibration done from it meets the drift a real one meets. Kinematics are
exact for a unit at rest on the Earth: with C_ib(t) = C_ie(t) C_en C_nb(t),
the gyro increment is the rotation from one sample to the next and the
velocity increment is C_bi(t_k-1) C_ie(t_mid) (-g_e) dt, whatever the table
does (the unit sits on the table's axis). The error model is sim/imu.py's;
gravity and Earth rate are sim/earth.py's (not the filter's).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from gpsins_logger import bp3010

from . import earth, imu
from .scenario import ImuModel


AXES = "xyz"
GPS_UNIX_OFFSET_S = 315964800.0
# A BP3010 record in a session file: sync, system-time stamp, 6 counts, status, counter, checksum.
RECORD = np.dtype([("sync", "u1"), ("stamp", "<f8"), ("counts", "<i2", (6,)), ("status", "u1"), ("counter", "u1"),
                   ("checksum", "u1")])


@dataclass
class LabDayConfig:
    """What the simulated lab day records (durations in seconds, rates in rad/s)."""

    position_s: float = 600.0  # each up-down position (the report: ten minutes)
    flip_s: float = 6.0  # turning the cube over
    table_rates_rad_per_s: tuple = (-2.0, -1.0, -0.5, -0.1, 0.1, 0.5, 1.0, 2.0)
    rate_run_min_s: float = 120.0  # each rate runs whole revolutions for at least this long
    ramp_s: float = 2.0  # table spin-up and spin-down
    drift_s: float = 7200.0  # the static drift run
    handling_s: float = 30.0  # between sessions: the bias wanders on, nothing is recorded
    lat_deg: float = 59.35
    lon_deg: float = 18.07
    height_m: float = 30.0
    drift_heading_deg: float = 0.0
    start_unix_s: float = 1.6e9
    imu: ImuModel = field(default_factory=ImuModel)

    @classmethod
    def quick(cls, **kw) -> "LabDayConfig":
        """A short day for tests: 40 s positions, 4 rates, 30 min drift run."""
        base = dict(position_s=40.0, table_rates_rad_per_s=(-2.0, -0.5, 0.5, 2.0), rate_run_min_s=15.0,
                    drift_s=1800.0, handling_s=10.0)
        base.update(kw)
        return cls(**base)


@dataclass
class Session:
    name: str
    kind: str  # updown | rate_table | drift
    i0: int  # sample range on the day's timeline
    i1: int
    axis: str | None = None
    rate_rad_per_s: float | None = None
    phases: list = field(default_factory=list)  # (label, t0, t1) relative to the session start


@dataclass
class LabDay:
    config: LabDayConfig
    seed: int
    rate_hz: int
    t: np.ndarray  # (n,) day time of each sample instant (end of its interval)
    dtheta: np.ndarray  # (n, 3) as the unit reports (before quantisation)
    dv: np.ndarray
    errors: imu.ImuErrors
    sessions: list[Session]
    earth_rate_body: np.ndarray  # (n, 3) true Earth rate seen by each axis
    table_rate_body: np.ndarray  # (n, 3) true table rate seen by each axis

    def true_bias(self, kind: str, i0: int, i1: int) -> np.ndarray:
        """Mean true bias (turn-on + drift) of each axis over samples i0:i1 of the day."""
        e = self.errors
        if kind == "gyro":
            return e.gyro_bias_rad_per_s + e.gyro_bias_drift[i0:i1].mean(0)
        return e.accel_bias_mps2 + e.accel_bias_drift[i0:i1].mean(0)

    def truth(self) -> dict:
        e = self.errors
        return {"gyro_scale_factor": (np.diag(e.gyro_matrix) - 1).tolist(),
                "accel_scale_factor": (np.diag(e.accel_matrix) - 1).tolist(),
                "gyro_turn_on_bias_rad_per_s": e.gyro_bias_rad_per_s.tolist(),
                "accel_turn_on_bias_mps2": e.accel_bias_mps2.tolist(),
                "gyro_matrix": e.gyro_matrix.tolist(), "accel_matrix": e.accel_matrix.tolist(),
                **{k: list(map(float, v)) for k, v in _noise(self.config.imu).items()}}


def _noise(m: ImuModel) -> dict:
    from . import imu_noise_truth

    return imu_noise_truth(m)["imu_noise"]

def _axis_up(i: int) -> np.ndarray:
    """C_nb with body axis i up, axis i+1 north (so axis i+2 west)."""
    c = np.zeros((3, 3))
    c[:, i] = (0.0, 0.0, -1.0)
    c[:, (i + 1) % 3] = (1.0, 0.0, 0.0)
    c[:, (i + 2) % 3] = np.cross(c[:, i], c[:, (i + 1) % 3])
    return c


def _rot_north(angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def _smooth(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x ** 3 * (10 - 15 * x + 6 * x * x)


def _smooth_integral(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x ** 4 * (2.5 - 3 * x + x * x)


def _updown_attitude(i: int, position_s: float, flip_s: float):
    up = _axis_up(i)

    def c_nb(t):
        phi = math.pi * _smooth((t - position_s) / flip_s)
        return _rot_north(phi) @ up
    return c_nb, position_s * 2 + flip_s, [("up", 0.0, position_s), ("flip", position_s, position_s + flip_s),
                                          ("down", position_s + flip_s, 2 * position_s + flip_s)]


def _table_attitude(i: int, w: float, run_s: float, ramp_s: float):
    """Axis i up on a vertical table turning at w (about up) for run_s between two ramps."""
    up = _axis_up(i)
    total = run_s + 2 * ramp_s

    def theta(t):
        up_part = ramp_s * _smooth_integral(t / ramp_s)
        steady = np.clip(t - ramp_s, 0.0, run_s)
        down_x = np.clip((t - ramp_s - run_s) / ramp_s, 0.0, 1.0)
        down_part = ramp_s * (down_x - _smooth_integral(down_x))
        return w * (up_part + steady + down_part)

    def c_nb(t):
        return earth.rot_z(-theta(t)) @ up  # a turn about up is a turn about down by -theta
    return c_nb, total, [("ramp", 0.0, ramp_s), ("steady", ramp_s, ramp_s + run_s), ("ramp", ramp_s + run_s, total)]


def _drift_attitude(heading_rad: float, duration_s: float):
    c = earth.rot_z(np.array(heading_rad))

    def c_nb(t):
        return np.broadcast_to(c, np.shape(t) + (3, 3))
    return c_nb, duration_s, [("static", 0.0, duration_s)]


def _plan_sessions(cfg: LabDayConfig):
    out = []
    for i, a in enumerate(AXES):
        f, d, ph = _updown_attitude(i, cfg.position_s, cfg.flip_s)
        out.append((f"updown_{a}", "updown", a, None, f, d, ph))
    for i, a in enumerate(AXES):
        for w in cfg.table_rates_rad_per_s:
            rev_s = 2 * math.pi / abs(w)
            run_s = math.ceil(cfg.rate_run_min_s / rev_s) * rev_s
            f, d, ph = _table_attitude(i, w, run_s, cfg.ramp_s)
            out.append((f"rate_{a}_{w:+.3f}".replace(".", "p").replace("+", "p").replace("-", "m"), "rate_table", a,
                        w, f, d, ph))
    f, d, ph = _drift_attitude(math.radians(cfg.drift_heading_deg), cfg.drift_s)
    out.append(("drift", "drift", None, None, f, d, ph))
    return out


def simulate_lab_day(cfg: LabDayConfig | None = None, seed: int = 0) -> LabDay:
    cfg = cfg or LabDayConfig()
    rate = int(cfg.imu.rate_hz)
    dt = 1.0 / rate
    lat, lon = math.radians(cfg.lat_deg), math.radians(cfg.lon_deg)
    c_en = earth.ecef_to_ned_matrix(np.array(lat), np.array(lon))
    g_e = earth.gravity_ecef(earth.geodetic_to_ecef(np.array(lat), np.array(lon), np.array(cfg.height_m)))
    w_ie_n = c_en.T @ earth.OMEGA_VEC
    plans = _plan_sessions(cfg)
    # One timeline: handling, session, handling, session, ...
    c_nb_all, sessions, cursor = [], [], 0
    t_all = []
    t_day = 0.0
    for name, kind, axis, w, c_nb, dur, phases in plans:
        n_h = int(round(cfg.handling_s * rate))
        n_s = int(round(dur * rate))
        # Handling: the unit sits in the session's first attitude (the motion itself is not recorded).
        tl = np.arange(n_h + n_s + 1) * dt  # +1: the instant that starts the first interval
        local = np.concatenate([np.zeros(n_h), tl[n_h:] - tl[n_h]])
        c_nb_all.append(c_nb(local) if n_h == 0 else np.concatenate([c_nb(np.zeros(n_h)), c_nb(local[n_h:])]))
        t_all.append(t_day + tl)
        sessions.append(Session(name, kind, cursor + n_h, cursor + n_h + n_s, axis, w, phases))
        cursor += n_h + n_s
        t_day += (n_h + n_s) * dt
    # Stitch: each block repeats the previous block's last instant as its first; keep it once.
    c_nb = np.concatenate([c_nb_all[0]] + [c[1:] for c in c_nb_all[1:]])
    t = np.concatenate([t_all[0]] + [x[1:] for x in t_all[1:]])
    c_ie = earth.rot_z(earth.OMEGA_E * t)
    c_ib = c_ie @ c_en @ c_nb
    rel = np.swapaxes(c_ib[:-1], -1, -2) @ c_ib[1:]
    dtheta_ideal = Rotation.from_matrix(rel).as_rotvec()
    t_mid = 0.5 * (t[:-1] + t[1:])
    f_i = np.einsum("nij,j->ni", earth.rot_z(earth.OMEGA_E * t_mid), -g_e)
    dv_ideal = np.einsum("nji,nj->ni", c_ib[:-1], f_i) * dt
    n = len(dtheta_ideal)
    rng = np.random.default_rng([seed, 0x1AB])
    errors = imu.draw_errors(cfg.imu, n, rng)
    dth, dvv = imu.measure(dtheta_ideal, dv_ideal, cfg.imu, errors, rng)
    c_bn = np.swapaxes(c_nb[1:], -1, -2)
    earth_body = c_bn @ w_ie_n
    table_body = dtheta_ideal / dt - earth_body
    return LabDay(cfg, seed, rate, t[1:], dth, dvv, errors, sessions, earth_body, table_body)

def encode_records(dtheta: np.ndarray, dv: np.ndarray, stamps: np.ndarray, rate_hz: int,
                   counter0: int = 1) -> bytes:
    """BP3010 frames with their stamps as the logger writes them (vectorised ImuSample.encode)."""
    n = len(dtheta)
    counts = np.concatenate([dtheta / bp3010.dtheta_lsb_rad(rate_hz), dv / bp3010.dv_lsb_mps(rate_hz)], 1)
    counts = np.round(counts)
    over = np.abs(counts) > 32767
    counts = np.clip(counts, -32768, 32767).astype("<i2")
    status = np.full(n, bp3010.STATUS_VALID, dtype=np.uint8)
    status |= np.where(over[:, :3].any(1), bp3010.STATUS_GYRO_OVERRANGE, 0).astype(np.uint8)
    status |= np.where(over[:, 3:].any(1), bp3010.STATUS_ACCEL_OVERRANGE, 0).astype(np.uint8)
    rec = np.zeros(n, RECORD)
    rec["sync"] = bp3010.SYNC
    rec["stamp"] = stamps
    rec["counts"] = counts
    rec["status"] = status
    rec["counter"] = (np.arange(n) + counter0) & 0xFF
    body = rec.view(np.uint8).reshape(n, RECORD.itemsize)[:, 9:23].astype(np.int64)
    rec["checksum"] = body.sum(1) & 0xFF
    return rec.tobytes()


def write_lab_day(day: LabDay, directory: str | Path, plan_name: str = "lab_plan.toml") -> Path:
    """One logger session directory per recording, the day's truth (truth.json) and the lab plan.
    Returns the plan's path."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=False)
    cfg = day.config
    rng = np.random.default_rng([day.seed, 0x57A])
    for s in day.sessions:
        d = directory / s.name
        d.mkdir()
        t = day.t[s.i0:s.i1]
        stamps = cfg.start_unix_s + t + 0.0005 + rng.exponential(0.0003, len(t))
        (d / "imu-000.bin").write_bytes(encode_records(day.dtheta[s.i0:s.i1], day.dv[s.i0:s.i1], stamps, day.rate_hz))
        start, stop = float(cfg.start_unix_s + t[0]), float(cfg.start_unix_s + t[-1])
        side = {
            "format": "gpsins-session", "format_version": 1,
            "software": {"name": "gpsins sim lab", "seed": day.seed}, "host": "simulated", "state": "stopped",
            "start": {"realtime": start, "monotonic": 1000.0 + float(t[0])},
            "stop": {"realtime": stop, "monotonic": 1000.0 + float(t[-1])},
            "stamp": "simulated: sample instant + 0.5 ms latency + exponential jitter",
            "sensors": {"imu": {"device": "bp3010", "header_len": 1, "baud": 38400, "rate_hz": day.rate_hz,
                                "files": ["imu-000.bin"], "raw_files": []}},
            "parts": [{"index": 0, "start": {"realtime": start, "monotonic": 1000.0 + float(t[0])}}],
            "counts": {"imu": {"frames_written": int(len(t))}}, "clock_steps": 0,
            "simulation": {"lab": s.kind, "axis": s.axis, "rate_rad_per_s": s.rate_rad_per_s,
                           "phases": s.phases, "day_samples": [s.i0, s.i1], "truth": "../truth.json"},
        }
        (d / "session.json").write_text(json.dumps(side, indent=2) + "\n", encoding="utf-8")
        with open(d / "clock.csv", "w", encoding="ascii") as f:
            f.write("realtime,monotonic\n")
            for tt in np.arange(t[0], t[-1], 10.0):
                f.write(f"{cfg.start_unix_s + tt!r},{1000.0 + tt!r}\n")
    (directory / "truth.json").write_text(json.dumps(truth_doc(day), indent=1, default=list) + "\n",
                                          encoding="utf-8")
    plan = directory / plan_name
    plan.write_text(plan_text(day), encoding="utf-8")
    return plan


def truth_doc(day: LabDay) -> dict:
    return {"seed": day.seed, "config": {k: v for k, v in asdict(day.config).items() if k != "imu"},
            "imu_model": {k: v for k, v in day.config.imu.__dict__.items()}, "unit": day.truth(),
            "sessions": [{"name": s.name, "kind": s.kind, "axis": s.axis, "rate_rad_per_s": s.rate_rad_per_s,
                          "day_samples": [s.i0, s.i1],
                          "mean_gyro_bias_rad_per_s": day.true_bias("gyro", s.i0, s.i1).tolist(),
                          "mean_accel_bias_mps2": day.true_bias("accel", s.i0, s.i1).tolist()}
                         for s in day.sessions]}


def plan_text(day: LabDay, names: list[str] | None = None) -> str:
    """The lab plan of the day's recordings (all, or those named)."""
    cfg = day.config
    chosen = [s for s in day.sessions if names is None or s.name in names]
    lines = [f"# Lab plan of a simulated BP3010 lab day (seed {day.seed}); truth in truth.json.",
             "[site]", f"lat_deg = {cfg.lat_deg!r}", f"height_m = {cfg.height_m!r}", ""]
    for s in chosen:
        if s.kind == "updown":
            lines += ["[[updown]]", f'session = "{s.name}"', ""]
    for s in chosen:
        if s.kind == "rate_table":
            lines += ["[[rate_table]]", f'session = "{s.name}"', f'axis = "{s.axis}"',
                      f"rate_rad_per_s = {s.rate_rad_per_s!r}", "axis_up = true", ""]
    if any(s.kind == "drift" for s in chosen):
        lines += ["[drift]", 'session = "drift"', f"heading_deg = {cfg.drift_heading_deg!r}", ""]
    return "\n".join(lines)
