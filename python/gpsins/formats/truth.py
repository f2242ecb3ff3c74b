"""The truth file (``truth.npz``), written block by block and read without loading it whole.

The file is a plain uncompressed NumPy ``.npz`` (``np.load`` opens it), holding
the truth at the IMU's sampling instants (the filter's epochs: the replay
interpolates between them), the receiver's true error terms per epoch, its fixes,
and the run's constants (see ``ARRAYS``). A day at 64 Hz is about 2.5 GB, so the
writer appends each block's rows to one raw file per array beside the target
and packs them into the archive at the end, streaming; the reader memory-maps
the arrays of the archive (members are stored, not deflated), so a replay
touches only the pages it reads.
"""

from __future__ import annotations

import json
import shutil
import struct
import zipfile
from pathlib import Path

import numpy as np

from gpsins_logger import bp3010

# Per-row arrays in file order: name -> (source, dtype). IMU-rate rows first, then the receiver's epochs, its fixes.
IMU_ROWS = ("t", "tow_s", "r_ecef", "v_ecef", "v_ned", "lat", "lon", "h", "q_eb", "ypr", "f_body", "w_ib_body",
            "imu_t", "ideal_dtheta", "ideal_dv", "gyro_bias", "accel_bias")
EPOCH_ROWS = ("gnss_t", "gnss_tow_rx", "clock_bias_s", "clock_drift", "tracked", "iono_m", "trop_m", "multipath_m")
FIX_ROWS = ("fix_t", "fix_mode", "fix_r_ecef", "fix_sats", "fix_hdop", "fix_vdop")
ORDER = (("gps_week", "t0_tow_s") + IMU_ROWS + ("gyro_matrix", "accel_matrix", "imu_dt") + EPOCH_ROWS + FIX_ROWS
         + ("segment_labels", "segment_t", "model_json"))
COPY_BYTES = 1 << 24
FIXED_TIME = (1980, 1, 1, 0, 0, 0)  # member times: the same bytes for the same run


def block_rows(b) -> dict[str, np.ndarray]:
    """A block's rows of every per-row array (``b``: a ``Simulation`` block)."""
    tr, g, e = b.truth, b.gnss, b.imu_errors
    i = b.truth_at_imu
    t0 = b.scenario.start.gps_tow_s
    f = g.fixes
    return dict(
        t=tr.t[i], tow_s=t0 + tr.t[i], r_ecef=tr.r_ecef[i], v_ecef=tr.v_ecef[i], v_ned=tr.v_ned[i], lat=tr.lat[i],
        lon=tr.lon[i], h=tr.h[i], q_eb=tr.q_eb[i], ypr=tr.ypr[i], f_body=tr.f_body[i], w_ib_body=tr.w_ib_body[i],
        imu_t=b.imu_t, ideal_dtheta=b.ideal_dtheta, ideal_dv=b.ideal_dv,
        gyro_bias=e.gyro_bias_rad_per_s + e.gyro_bias_drift, accel_bias=e.accel_bias_mps2 + e.accel_bias_drift,
        gnss_t=g.t, gnss_tow_rx=g.tow_rx, clock_bias_s=g.clock.bias_s, clock_drift=g.clock.drift_s_per_s,
        tracked=g.tracked, iono_m=g.iono_m, trop_m=g.trop_m, multipath_m=g.multipath_m,
        fix_t=np.array([x.t for x in f], dtype=np.float64), fix_mode=np.array([x.mode for x in f], dtype=np.int64),
        fix_r_ecef=np.array([x.r_ecef for x in f], dtype=np.float64).reshape(-1, 3),
        fix_sats=np.array([x.sats for x in f], dtype=np.int64),
        fix_hdop=np.array([x.hdop for x in f], dtype=np.float64), fix_vdop=np.array([x.vdop for x in f],
                                                                                    dtype=np.float64))


def run_constants(b) -> dict[str, np.ndarray]:
    """The run-wide entries: start, the unit's drawn matrices, segments and the models (as JSON)."""
    sc, e = b.scenario, b.imu_errors
    segments = sc.segment_times()
    model = {"scenario": sc.name, "seed": getattr(b, "seed", None),
             "imu": {k: v for k, v in sc.imu.__dict__.items()}, "gnss": dict(sc.gnss.__dict__),
             "timing": dict(sc.timing.__dict__), "imu_errors": e.as_dict(),
             "bp3010_lsb": {"dtheta_rad": bp3010.dtheta_lsb_rad(b.imu_rate_hz),
                            "dv_mps": bp3010.dv_lsb_mps(b.imu_rate_hz)}}
    return dict(gps_week=np.int64(sc.start.gps_week), t0_tow_s=np.float64(sc.start.gps_tow_s),
                gyro_matrix=e.gyro_matrix, accel_matrix=e.accel_matrix, imu_dt=np.float64(1.0 / b.imu_rate_hz),
                segment_labels=np.array([s[0] for s in segments]),
                segment_t=np.array([[s[1], s[2]] for s in segments]).reshape(-1, 2),
                model_json=np.array(json.dumps(model, default=list)))


class TruthWriter:
    """``add`` blocks in order, then ``close`` (or ``abort``)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.parts = self.path.with_name(self.path.name + ".parts")
        self.parts.mkdir(exist_ok=False)
        self._files: dict[str, object] = {}
        self._layout: dict[str, tuple[np.dtype, tuple, int]] = {}  # dtype, row shape, rows
        self._constants: dict | None = None

    def add(self, b) -> None:
        if self._constants is None:
            self._constants = run_constants(b)
        for name, rows in block_rows(b).items():
            rows = np.ascontiguousarray(rows)
            if name not in self._files:
                self._files[name] = open(self.parts / name, "wb")
                self._layout[name] = (rows.dtype, rows.shape[1:], 0)
            dtype, shape, n = self._layout[name]
            if rows.dtype != dtype or rows.shape[1:] != shape:
                raise ValueError(f"{self.path}: {name}: block rows {rows.dtype}{rows.shape[1:]} after {dtype}{shape}")
            self._files[name].write(rows.tobytes())
            self._layout[name] = (dtype, shape, n + len(rows))

    def close(self) -> Path:
        for f in self._files.values():
            f.close()
        if self._constants is None:
            raise ValueError(f"{self.path}: no block was written")
        tmp = self.path.with_name(self.path.name + ".tmp")
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED, allowZip64=True) as z:
            for name in ORDER:
                info = zipfile.ZipInfo(name + ".npy", FIXED_TIME)
                info.compress_type = zipfile.ZIP_STORED
                with z.open(info, "w", force_zip64=True) as out:
                    if name in self._layout:
                        dtype, shape, n = self._layout[name]
                        _header(out, dtype, (n,) + shape)
                        with open(self.parts / name, "rb") as src:
                            shutil.copyfileobj(src, out, COPY_BYTES)
                    else:
                        a = np.asarray(self._constants[name])
                        _header(out, a.dtype, a.shape)
                        out.write(np.ascontiguousarray(a).tobytes())
        tmp.replace(self.path)
        shutil.rmtree(self.parts)
        return self.path

    def abort(self) -> None:
        for f in self._files.values():
            f.close()
        shutil.rmtree(self.parts, ignore_errors=True)


def _header(out, dtype: np.dtype, shape: tuple) -> None:
    np.lib.format.write_array_header_1_0(out, {"descr": np.lib.format.dtype_to_descr(np.dtype(dtype)),
                                               "fortran_order": False, "shape": tuple(int(x) for x in shape)})


def write_truth(sim, path: str | Path) -> Path:
    """A whole simulation's truth file."""
    w = TruthWriter(path)
    w.add(sim)
    return w.close()


LOCAL_HEADER = struct.Struct("<4s5H3L2H")  # zip local file header, 30 bytes


def open_truth(path: str | Path) -> dict[str, np.ndarray]:
    """Every array of a truth file, memory-mapped read-only where stored uncompressed (loaded otherwise):
    a day-long file opens at once and only the pages read are brought in."""
    path = Path(path)
    out = {}
    with zipfile.ZipFile(path) as z, open(path, "rb") as f:
        for info in z.infolist():
            name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
            if info.compress_type != zipfile.ZIP_STORED:
                with z.open(info) as m:
                    out[name] = np.lib.format.read_array(m, allow_pickle=False)
                continue
            f.seek(info.header_offset)
            fields = LOCAL_HEADER.unpack(f.read(LOCAL_HEADER.size))
            if fields[0] != b"PK\x03\x04":
                raise ValueError(f"{path}: member {info.filename}: bad local header at byte {info.header_offset}")
            f.seek(info.header_offset + LOCAL_HEADER.size + fields[-2] + fields[-1])
            version = np.lib.format.read_magic(f)
            shape, fortran, dtype = (np.lib.format.read_array_header_1_0(f) if version == (1, 0)
                                     else np.lib.format.read_array_header_2_0(f))
            if dtype.hasobject:
                raise ValueError(f"{path}: member {info.filename}: object arrays are not truth")
            if 0 in shape or not shape:  # empty or a scalar: read it (memmap cannot map nothing)
                count = int(np.prod(shape)) if shape else 1
                out[name] = np.fromfile(f, dtype=dtype, count=count).reshape(shape)
                continue
            out[name] = np.memmap(path, dtype=dtype, mode="r", offset=f.tell(), shape=shape,
                                  order="F" if fortran else "C")
    return out


def load_truth(path: str | Path) -> dict:
    """Every array of a truth file in memory, with the models' JSON parsed as ``model``."""
    with np.load(path) as z:
        out = {k: z[k] for k in z.files}
    out["model"] = json.loads(str(out.pop("model_json")))
    return out
