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

from ..formats import reference as reference_file
from . import DEFAULT_BLOCK_S, Simulation, Simulator, reference
from .draws import Stream
from .messages import GpsMessages
from ..formats.truth import TruthWriter, load_truth, write_truth
from ..formats.gpstime import SECONDS_PER_WEEK

__all__ = ["SessionWriter", "simulate_session", "write_session", "write_reference", "write_truth", "load_truth",
           "realtime", "imu_frames", "imu_records"]

GPS_UNIX_OFFSET_S = 315964800.0  # 1980-01-06 in Unix time
STAMP = struct.Struct("<d")


def realtime(sim, t: np.ndarray) -> np.ndarray:
    """System clock reading at true run time t (``sim``: anything with the run's ``scenario``)."""
    sc = sim.scenario
    base = GPS_UNIX_OFFSET_S + sc.start.gps_week * SECONDS_PER_WEEK + sc.start.gps_tow_s - sc.gnss.leap_seconds
    out = base + np.asarray(t, dtype=np.float64) + sc.timing.system_clock_offset_s
    if sc.timing.clock_step_at_s is not None:
        out = out + np.where(np.asarray(t) >= sc.timing.clock_step_at_s, sc.timing.clock_step_s, 0.0)
    return out


def _load_stalls(sc, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(start, end) run times of the host's stalls; none (and no draws) when switched off. A few numbers
    per stall, drawn for the whole run up front (the stalls of a day at one a minute: 23 kB)."""
    tm = sc.timing
    if tm.load_stall_rate_hz <= 0:
        return np.zeros(0), np.zeros(0)
    rng = np.random.default_rng([seed, 4])
    n = rng.poisson(tm.load_stall_rate_hz * sc.duration_s)
    start = np.sort(rng.uniform(0.0, sc.duration_s, n))
    shape = 2.5  # Pareto: mean = x_m shape / (shape - 1)
    length = tm.load_stall_mean_s * (shape - 1) / shape * (1.0 + rng.pareto(shape, n))
    return start, np.maximum.accumulate(start + length)


def _stall_delay(x: np.ndarray, stalls: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Extra delay of stamps taken at run times x: up to the end of a stall that holds them."""
    start, end = stalls
    if not len(start):
        return np.zeros(len(x))
    k = np.searchsorted(start, x, side="right") - 1
    # Stalls may overlap: `end` is the latest end among those started up to each one.
    reach = end[np.maximum(k, 0)]
    return np.where((k >= 0) & (x < reach), reach - x, 0.0)


class _InOrder:
    """Stamps as the logger gives them: a port is read in order and a sensor's stamps never run
    backwards (each at least one byte time after the one before), so a frame delayed by the host
    holds back the frames queued behind it. Carries the run's frame count and hold-back."""

    def __init__(self, step_s: float):
        self.step_s, self.count, self.held = step_s, 0, -np.inf

    def __call__(self, t: np.ndarray) -> np.ndarray:
        k = np.arange(self.count, self.count + len(t)) * self.step_s
        held = np.maximum.accumulate(np.concatenate([[self.held], t - k]))
        self.count, self.held = self.count + len(t), held[-1]
        return held[1:] + k


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


class SessionWriter:
    """A session directory written block by block (``Simulation`` blocks in order): the GPS and IMU
    record files, the reference beside them and the truth file grow as the blocks come; ``close``
    writes the clock pairs and the sidecar. The stamps' draws (jitter, dropped IMU frames) are
    addressed by frame, and the line queue, hold-back and ephemeris schedule carry over, so the
    files are the same bytes however the run is cut."""

    def __init__(self, sc, seed: int, directory: str | Path):
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=False)
        self.scenario = sc
        self.seed, tm = seed, sc.timing
        self.imu_rate_hz = sc.imu.rate_hz
        self.stalls = _load_stalls(sc, seed)
        self.jitter = {name: Stream((seed, 3, j), "exponential") for j, name in ((1, "gps"), (3, "imu"))}
        self.drop = Stream((seed, 3, 2), "uniform")
        self.messages = GpsMessages(sc.gnss.leap_seconds)
        self.byte_s = 10.0 / tm.gps_baud
        self.gps_free = -np.inf  # when the line is next free
        self.gps_order, self.imu_order = _InOrder(self.byte_s), _InOrder(10.0 / tm.imu_baud)
        self.gps_file = open(self.directory / "gps-000.bin", "wb")
        self.imu_file = open(self.directory / "imu-000.bin", "wb")
        self.n_imu = self.n_dropped = 0
        self.ref_file = None
        if sc.reference.enabled:
            m = sc.reference
            self.ref_file = open(self.directory / reference_file.FILE_NAME, "w", encoding="ascii")
            self.ref_file.write("\n".join(reference_file.header_lines(
                f"simulated: scenario {sc.name}, seed {seed}, {m.rate_hz} Hz, baseline {m.baseline_m} m, "
                f"RTK {m.rtk_3d_rms_m} m 3D RMS")) + "\n")
        self.truth = TruthWriter(self.directory / "truth.npz")

    def add(self, b: Simulation) -> None:
        sc, tm = self.scenario, self.scenario.timing
        # GPS: frames queue on the line in emission order.
        msgs = self.messages(b.gnss, b.last)
        if msgs:
            first = np.empty(len(msgs))
            free = self.gps_free
            for k, m in enumerate(msgs):
                first[k] = max(m.t, free)
                free = first[k] + len(m.frame) * self.byte_s
            self.gps_free = free
            k0 = self.gps_order.count
            jitter = self.jitter["gps"].rows(k0, k0 + len(msgs)) * tm.jitter_mean_s if tm.jitter_mean_s > 0 else 0.0
            delay = tm.gps_latency_s + jitter
            arrival = first + delay + _stall_delay(first + delay, self.stalls)
            read = self.gps_order(np.maximum(arrival, tm.gps_setup_hold_s))
            stamps = realtime(b, first) + (read - first)
            self.gps_file.write(_records([m.frame for m in msgs], stamps, ss2.HEADER_LEN))
        # IMU: one frame per sample, some dropped if configured; the counter counts every sample.
        n = len(b.imu_t)
        i0, i1 = b.imu_i0, b.imu_i0 + n
        keep = (self.drop.rows(i0, i1) >= tm.imu_drop_probability if tm.imu_drop_probability > 0
                else np.ones(n, dtype=bool))
        frames = imu_frames(b.imu_dtheta, b.imu_dv, np.arange(i0 + 1, i1 + 1), self.imu_rate_hz)
        jitter = self.jitter["imu"].rows(i0, i1) * tm.jitter_mean_s if tm.jitter_mean_s > 0 else 0.0
        arrival = b.imu_t + tm.imu_latency_s + jitter
        arrival = arrival + _stall_delay(arrival, self.stalls)
        kept = np.flatnonzero(keep)
        read = self.imu_order(arrival[kept])  # dropped frames are never read
        stamps = realtime(b, b.imu_t[kept]) + (read - b.imu_t[kept])
        self.imu_file.write(imu_records(frames[kept], stamps))
        self.n_imu += len(kept)
        self.n_dropped += n - len(kept)
        if self.ref_file is not None and b.reference is not None and len(b.reference.t):
            ref = b.reference
            lines = reference_file.row_lines(sc.start.gps_week, sc.start.gps_tow_s + ref.t, ref.r_ecef,
                                             ref.sigma_ned_m, ref.heading_rad, ref.pitch_rad, ref.sigma_heading_rad,
                                             ref.sigma_pitch_rad)
            self.ref_file.write("".join(line + "\n" for line in lines))
        self.truth.add(b)

    def close(self) -> Path:
        sc, tm, directory = self.scenario, self.scenario.timing, self.directory
        self.gps_file.close()
        self.imu_file.close()
        if self.ref_file is not None:
            self.ref_file.close()
        self.truth.close()
        start = float(realtime(self, 0.0))
        stop = float(realtime(self, sc.duration_s))
        # Clock pairs: the simulated host's monotonic clock starts at 1000 s.
        with open(directory / "clock.csv", "w", encoding="ascii") as f:
            f.write("realtime,monotonic\n")
            for t in np.arange(0.0, sc.duration_s, 10.0):
                f.write(f"{float(realtime(self, t))!r},{float(1000.0 + t)!r}\n")
        sidecar = {
            "format": "gpsins-session",
            "format_version": 1,
            "software": {"name": "gpsins sim", "scenario": sc.name, "seed": self.seed},
            "host": "simulated",
            "state": "stopped",
            "start": {"realtime": start, "monotonic": 1000.0},
            "stop": {"realtime": stop, "monotonic": 1000.0 + sc.duration_s},
            "stamp": "simulated: realtime of the frame's first byte + latency + exponential jitter + host stalls "
                     "if any, in read order (never backwards per sensor)",
            "sensors": {
                "gps": {"device": "superstar2", "header_len": ss2.HEADER_LEN, "baud": tm.gps_baud,
                        "files": ["gps-000.bin"], "raw_files": []},
                "imu": {"device": "bp3010", "header_len": 1, "baud": tm.imu_baud, "rate_hz": self.imu_rate_hz,
                        "files": ["imu-000.bin"], "raw_files": []},
            },
            "parts": [{"index": 0, "start": {"realtime": start, "monotonic": 1000.0}}],
            "counts": {"gps": {"frames_written": self.gps_order.count},
                       "imu": {"frames_written": self.n_imu, "frames_dropped_by_simulation": self.n_dropped}},
            "clock_steps": int(tm.clock_step_at_s is not None),
            "simulation": {
                "scenario": sc.name, "seed": self.seed, "timing": dict(tm.__dict__),
                "gps_start": {"week": sc.start.gps_week, "tow_s": sc.start.gps_tow_s},
                "leap_seconds": sc.gnss.leap_seconds, "truth": "truth.npz",
            },
        }
        if self.imu_rate_hz not in bp3010.RATES_HZ:
            sidecar["simulation"]["imu_frame"] = (
                f"BP3010 frame layout at {self.imu_rate_hz} Hz, not a BP3010 rate: LSBs scaled by "
                f"{bp3010.NOMINAL_RATE_HZ} / rate_hz, counter +1 per sample")
        if self.ref_file is not None:
            sidecar["simulation"]["reference"] = reference_file.FILE_NAME
        (directory / "session.json").write_text(json.dumps(sidecar, indent=2) + "\n", encoding="utf-8")
        return directory


def write_session(sim: Simulation, directory: str | Path) -> Path:
    """A whole simulation (or a run's only block) as a session directory."""
    w = SessionWriter(sim.scenario, sim.seed, directory)
    w.add(sim)
    return w.close()


def simulate_session(sc, seed: int, directory: str | Path, block_s: float | None = DEFAULT_BLOCK_S,
                     dataset: str | Path | None = None, fix_rate_hz: float = 5.0) -> Path:
    """Simulate and write a session block by block: memory bounded by the block, not the drive.
    ``dataset``: also write the run as a data set there (``dataset_writer``, default options but
    ``fix_rate_hz`` fixes per second)."""
    from .dataset_writer import DatasetWriter

    sim = Simulator(sc, seed)
    w = SessionWriter(sc, seed, directory)
    ds = DatasetWriter(sc, seed, dataset, sim.truth.t_end, gnss_rate_hz=fix_rate_hz) if dataset is not None else None
    try:
        for b in sim.blocks(block_s):
            w.add(b)
            if ds is not None:
                ds.add(b)
    except BaseException:
        w.truth.abort()
        raise
    if ds is not None:
        ds.close()
    return w.close()


def write_reference(sim: Simulation, path: str | Path) -> reference.ReferenceData:
    """The dual-antenna RTK reference's file (gpsins.reference's layout) of a whole simulation, GPS-timed."""
    sc, m, ref = sim.scenario, sim.scenario.reference, sim.reference
    reference_file.write(path, sc.start.gps_week, sc.start.gps_tow_s + ref.t, ref.r_ecef, ref.sigma_ned_m,
                         ref.heading_rad, ref.pitch_rad, ref.sigma_heading_rad, ref.sigma_pitch_rad,
                         comment=f"simulated: scenario {sc.name}, seed {sim.seed}, {m.rate_hz} Hz, "
                                 f"baseline {m.baseline_m} m, RTK {m.rtk_3d_rms_m} m 3D RMS")
    return ref
