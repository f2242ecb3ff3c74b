"""A simulation written as files: a logger session directory (for fast tests,
without ptys) and the truth.

System-time stamps follow the model the time-alignment stage must undo:
stamp = realtime(first byte) + constant latency per device + non-negative
(exponential) jitter + the wait to the end of a host stall (optional,
heavy-tailed), where realtime = true UTC + the system clock's offset (+ an
optional step). GPS frames sent at the same moment leave the port one
after another at the line's byte time. As the logger reads a port in order
and never lets a sensor's stamps run backwards, a delayed frame holds back the
frames behind it (each stamp at least a byte time after the last). The model's parameters are recorded in
the sidecar's ``simulation`` block.

The IMU file holds BP3010 frames at the scenario's rate: the sidecar's
``sensors.imu.rate_hz`` gives the rate, which sets the frames' LSBs (64 / rate
times the 64 Hz ones, spec/bp3010.md) and the counter's period (256 samples).
Rates the real unit does not have (50, 100, 200, 400 Hz) keep that layout and
say so in the ``simulation`` block (``imu_frame``); the readers need nothing
else.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

from gpsins_logger import bp3010
from gpsins_logger import superstar2 as ss2

from .. import reference as reference_file
from . import Simulation, reference
from .messages import SimSource

GPS_UNIX_OFFSET_S = 315964800.0  # 1980-01-06 in Unix time
STAMP = struct.Struct("<d")


def realtime(sim: Simulation, t: np.ndarray) -> np.ndarray:
    """System clock reading at true run time t."""
    sc = sim.scenario
    base = GPS_UNIX_OFFSET_S + sc.start.gps_week * 604800.0 + sc.start.gps_tow_s - sc.gnss.leap_seconds
    out = base + np.asarray(t, dtype=np.float64) + sc.timing.system_clock_offset_s
    if sc.timing.clock_step_at_s is not None:
        out = out + np.where(np.asarray(t) >= sc.timing.clock_step_at_s, sc.timing.clock_step_s, 0.0)
    return out


def _jitter(rng: np.random.Generator, n: int, mean_s: float) -> np.ndarray | float:
    """Non-negative stamp jitter; no draws when it is switched off."""
    return rng.exponential(mean_s, n) if mean_s > 0 else 0.0


def _load_stalls(sim: Simulation) -> tuple[np.ndarray, np.ndarray]:
    """(start, end) run times of the host's stalls; none (and no draws) when switched off."""
    tm = sim.scenario.timing
    if tm.load_stall_rate_hz <= 0:
        return np.zeros(0), np.zeros(0)
    rng = np.random.default_rng([sim.seed, 4])
    n = rng.poisson(tm.load_stall_rate_hz * sim.scenario.duration_s)
    start = np.sort(rng.uniform(0.0, sim.scenario.duration_s, n))
    shape = 2.5  # Pareto: mean = x_m shape / (shape - 1)
    length = tm.load_stall_mean_s * (shape - 1) / shape * (1.0 + rng.pareto(shape, n))
    return start, start + length


def _stall_delay(x: np.ndarray, stalls: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Extra delay of stamps taken at run times x: up to the end of a stall that holds them."""
    start, end = stalls
    if not len(start):
        return np.zeros(len(x))
    k = np.searchsorted(start, x, side="right") - 1
    # Stalls may overlap: the latest end among those started before x.
    reach = np.maximum.accumulate(end)[np.maximum(k, 0)]
    return np.where((k >= 0) & (x < reach), reach - x, 0.0)


def _in_order(t: np.ndarray, step_s: float) -> np.ndarray:
    """Stamps as the logger gives them: a port is read in order and a sensor's stamps never run
    backwards (each at least one byte time after the one before), so a frame delayed by the host
    holds back the frames queued behind it."""
    k = np.arange(len(t)) * step_s
    return np.maximum.accumulate(t - k) + k


def _records(frames: list[bytes], stamps: np.ndarray, header_len: int) -> bytes:
    return b"".join(f[:header_len] + STAMP.pack(s) + f[header_len:] for f, s in zip(frames, stamps))


def imu_frames(dtheta: np.ndarray, dv: np.ndarray, counter: np.ndarray, rate_hz: int) -> np.ndarray:
    """(n, 16) uint8 BP3010 frames of valid samples, as ``bp3010.ImuSample.encode`` makes them one
    by one (round half to even, saturation flagged), built for the whole run at once."""
    n = len(dtheta)
    status = np.full(n, bp3010.STATUS_VALID, dtype=np.int64)
    counts = np.empty((n, 6), dtype=np.int64)
    for cols, values, lsb, flag in (((0, 3), dtheta, bp3010.dtheta_lsb_rad(rate_hz), bp3010.STATUS_GYRO_OVERRANGE),
                                    ((3, 6), dv, bp3010.dv_lsb_mps(rate_hz), bp3010.STATUS_ACCEL_OVERRANGE)):
        c = np.rint(np.where(np.isfinite(values), values / lsb, 0.0))
        over = np.any((c < -32768) | (c > 32767), axis=1)
        status[over] |= flag
        counts[:, cols[0]:cols[1]] = np.clip(c, -32768, 32767)
    body = np.zeros((n, bp3010.FRAME_LEN - 2), dtype=np.uint8)
    body[:, :12] = counts.astype("<i2").view(np.uint8).reshape(n, 12)
    body[:, 12] = status & 0xFF
    body[:, 13] = np.asarray(counter, dtype=np.int64) & 0xFF
    frames = np.empty((n, bp3010.FRAME_LEN), dtype=np.uint8)
    frames[:, 0] = bp3010.SYNC
    frames[:, 1:bp3010.CHECKSUM_OFFSET] = body
    frames[:, bp3010.CHECKSUM_OFFSET] = body.sum(axis=1, dtype=np.int64) & 0xFF
    return frames


def imu_records(frames: np.ndarray, stamps: np.ndarray) -> bytes:
    """Record bytes `sync | f8 stamp | frame bytes 1..15` for (n, 16) frames."""
    n = len(frames)
    rec = np.empty((n, bp3010.FRAME_LEN + STAMP.size), dtype=np.uint8)
    rec[:, 0] = frames[:, 0]
    rec[:, 1:1 + STAMP.size] = np.asarray(stamps, dtype="<f8").reshape(n, 1).view(np.uint8)
    rec[:, 1 + STAMP.size:] = frames[:, 1:]
    return rec.tobytes()


def write_session(sim: Simulation, directory: str | Path) -> Path:
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=False)
    sc, tm = sim.scenario, sim.scenario.timing
    rng = np.random.default_rng([sim.seed, 3])
    src = SimSource(sim)
    # GPS: frames queue on the line in emission order.
    msgs = list(src.gps_messages())
    byte_s = 10.0 / tm.gps_baud
    first = np.empty(len(msgs))
    free = -np.inf
    for k, m in enumerate(msgs):
        first[k] = max(m.t, free)
        free = first[k] + len(m.frame) * byte_s
    stalls = _load_stalls(sim)
    gps_delay = tm.gps_latency_s + _jitter(rng, len(msgs), tm.jitter_mean_s)
    gps_read = _in_order(first + gps_delay + _stall_delay(first + gps_delay, stalls), byte_s)
    gps_stamps = realtime(sim, first) + (gps_read - first)
    (directory / "gps-000.bin").write_bytes(_records([m.frame for m in msgs], gps_stamps, ss2.HEADER_LEN))
    # IMU: one frame per sample, some dropped if configured; the counter counts every sample.
    n_imu = len(sim.imu_t)
    keep = rng.random(n_imu) >= tm.imu_drop_probability
    frames = imu_frames(sim.imu_dtheta, sim.imu_dv, np.arange(1, n_imu + 1), sim.imu_rate_hz)
    arrival = sim.imu_t + tm.imu_latency_s + _jitter(rng, n_imu, tm.jitter_mean_s)
    arrival = arrival + _stall_delay(arrival, stalls)
    kept = np.flatnonzero(keep)
    read = _in_order(arrival[kept], 10.0 / tm.imu_baud)  # dropped frames are never read
    imu_stamps = realtime(sim, sim.imu_t[kept]) + (read - sim.imu_t[kept])
    (directory / "imu-000.bin").write_bytes(imu_records(frames[kept], imu_stamps))
    start = float(realtime(sim, 0.0))
    stop = float(realtime(sim, sc.duration_s))
    # Clock pairs: the simulated host's monotonic clock starts at 1000 s.
    pairs = np.arange(0.0, sc.duration_s, 10.0)
    with open(directory / "clock.csv", "w", encoding="ascii") as f:
        f.write("realtime,monotonic\n")
        for t in pairs:
            f.write(f"{float(realtime(sim, t))!r},{float(1000.0 + t)!r}\n")
    sidecar = {
        "format": "gpsins-session",
        "format_version": 1,
        "software": {"name": "gpsins sim", "scenario": sc.name, "seed": sim.seed},
        "host": "simulated",
        "state": "stopped",
        "start": {"realtime": start, "monotonic": 1000.0},
        "stop": {"realtime": stop, "monotonic": 1000.0 + sc.duration_s},
        "stamp": "simulated: realtime of the frame's first byte + latency + exponential jitter + host stalls "
                 "if any, in read order (never backwards per sensor)",
        "sensors": {
            "gps": {"device": "superstar2", "header_len": ss2.HEADER_LEN, "baud": tm.gps_baud,
                    "files": ["gps-000.bin"], "raw_files": []},
            "imu": {"device": "bp3010", "header_len": 1, "baud": tm.imu_baud, "rate_hz": sim.imu_rate_hz,
                    "files": ["imu-000.bin"], "raw_files": []},
        },
        "parts": [{"index": 0, "start": {"realtime": start, "monotonic": 1000.0}}],
        "counts": {"gps": {"frames_written": len(msgs)}, "imu": {"frames_written": int(len(kept)),
                                                                "frames_dropped_by_simulation": int((~keep).sum())}},
        "clock_steps": int(tm.clock_step_at_s is not None),
        "simulation": {
            "scenario": sc.name, "seed": sim.seed, "timing": dict(tm.__dict__),
            "gps_start": {"week": sc.start.gps_week, "tow_s": sc.start.gps_tow_s},
            "leap_seconds": sc.gnss.leap_seconds, "truth": "truth.npz",
        },
    }
    if sim.imu_rate_hz not in bp3010.RATES_HZ:
        sidecar["simulation"]["imu_frame"] = (
            f"BP3010 frame layout at {sim.imu_rate_hz} Hz, not a BP3010 rate: LSBs scaled by "
            f"{bp3010.NOMINAL_RATE_HZ} / rate_hz, counter +1 per sample")
    if sc.reference.enabled:
        write_reference(sim, directory / reference_file.FILE_NAME)
        sidecar["simulation"]["reference"] = reference_file.FILE_NAME
    (directory / "session.json").write_text(json.dumps(sidecar, indent=2) + "\n", encoding="utf-8")
    write_truth(sim, directory / "truth.npz")
    return directory


def write_reference(sim: Simulation, path: str | Path) -> reference.ReferenceData:
    """The dual-antenna RTK reference's file (gpsins.reference's layout), GPS-timed."""
    sc = sim.scenario
    ref = reference.simulate(sim, sc.reference, np.random.default_rng([sim.seed, sc.reference.seed_offset]))
    m = sc.reference
    reference_file.write(path, sc.start.gps_week, sc.start.gps_tow_s + ref.t, ref.r_ecef, ref.sigma_ned_m,
                         ref.heading_rad, ref.pitch_rad, ref.sigma_heading_rad, ref.sigma_pitch_rad,
                         comment=f"simulated: scenario {sc.name}, seed {sim.seed}, {m.rate_hz} Hz, "
                                 f"baseline {m.baseline_m} m, RTK {m.rtk_3d_rms_m} m 3D RMS")
    return ref


def write_truth(sim: Simulation, path: str | Path) -> None:
    """Truth at the IMU's sampling instants plus the receiver's true error terms (NumPy .npz)."""
    tr, g, e = sim.truth, sim.gnss, sim.imu_errors
    i = sim.truth_at_imu
    sc = sim.scenario
    dt = 1.0 / sim.imu_rate_hz
    arrays = dict(
        gps_week=np.int64(sc.start.gps_week), t0_tow_s=np.float64(sc.start.gps_tow_s),
        t=tr.t[i], tow_s=sc.start.gps_tow_s + tr.t[i], r_ecef=tr.r_ecef[i], v_ecef=tr.v_ecef[i], v_ned=tr.v_ned[i],
        lat=tr.lat[i], lon=tr.lon[i], h=tr.h[i], q_eb=tr.q_eb[i], ypr=tr.ypr[i], f_body=tr.f_body[i],
        w_ib_body=tr.w_ib_body[i], imu_t=sim.imu_t, ideal_dtheta=sim.ideal_dtheta, ideal_dv=sim.ideal_dv,
        gyro_bias=e.gyro_bias_rad_per_s + e.gyro_bias_drift, accel_bias=e.accel_bias_mps2 + e.accel_bias_drift,
        gyro_matrix=e.gyro_matrix, accel_matrix=e.accel_matrix, imu_dt=np.float64(dt),
        gnss_t=g.t, gnss_tow_rx=g.tow_rx, clock_bias_s=g.clock.bias_s, clock_drift=g.clock.drift_s_per_s,
        tracked=g.tracked, iono_m=g.iono_m, trop_m=g.trop_m, multipath_m=g.multipath_m,
        fix_t=np.array([f.t for f in g.fixes]), fix_mode=np.array([f.mode for f in g.fixes]),
        fix_r_ecef=np.array([f.r_ecef for f in g.fixes]), fix_sats=np.array([f.sats for f in g.fixes]),
        fix_hdop=np.array([f.hdop for f in g.fixes]), fix_vdop=np.array([f.vdop for f in g.fixes]),
        segment_labels=np.array([s[0] for s in sc.segment_times()]),
        segment_t=np.array([[s[1], s[2]] for s in sc.segment_times()]),
    )
    model = {"imu": {k: v for k, v in sc.imu.__dict__.items()}, "gnss": dict(sc.gnss.__dict__),
             "timing": dict(sc.timing.__dict__), "imu_errors": e.as_dict(),
             "bp3010_lsb": {"dtheta_rad": bp3010.dtheta_lsb_rad(sim.imu_rate_hz),
                            "dv_mps": bp3010.dv_lsb_mps(sim.imu_rate_hz)}}
    arrays["model_json"] = np.array(json.dumps(model, default=list))
    with open(path, "wb") as f:
        np.savez(f, **arrays)


def load_truth(path: str | Path) -> dict:
    with np.load(path) as z:
        out = {k: z[k] for k in z.files}
    out["model"] = json.loads(str(out.pop("model_json")))
    return out
