"""Reader speed on an hour of data: `python benchmarks/bench_readers.py [--pyubx2-full]`.

- IMU CSV: a synthetic 1-hour 100 Hz table laid out like the walk's (GPST Unix seconds,
  accelerometer in g, gyro in rad/s, four unused columns; 360,000 rows), read by
  ``readers.imu_csv`` (rates to increments included).
- UBX: the walk's 134 s capture (RAWX, SFRBX, NAV-PVT and NMEA at 4 Hz) repeated to an
  hour (27 copies), read by ``readers.ubx``; pyubx2 on one copy for comparison, scaled to
  the hour (``--pyubx2-full`` runs it on the whole hour).
- The loosely coupled filter on an hour at 100 Hz (1 Hz fixes), the time the readers are
  measured against.

Prints seconds, rows or frames per second and peak RSS.
"""

import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gpsins import filter as flt
from gpsins.readers import imu_csv, ubx

WALK_UBX = Path(__file__).resolve().parents[1] / "tests" / "data" / "walk_0827" / "gnss_1730.ubx"


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def write_csv(path: Path, seconds: float = 3600.0, rate: float = 100.0) -> int:
    n = int(seconds * rate)
    rng = np.random.default_rng(0)
    t = 1756402240.961 + np.arange(n) / rate + rng.uniform(0, 5e-4, n)
    acc = rng.normal([0, 0, 1], 0.02, (n, 3))
    gyr = rng.normal(0, 0.01, (n, 3))
    a = np.column_stack([t, acc, gyr, np.zeros((n, 4))])
    np.savetxt(path, a, delimiter=",", fmt=["%.7f"] + ["%.7f"] * 10)
    return n


def filter_hour() -> float:
    n = 360_000
    dt = 0.01
    t = np.arange(1, n + 1) * dt
    imu = np.zeros((n, 7))
    imu[:, 0] = t
    imu[:, 6] = -9.81 * dt  # standing, level (increments along body down)
    r0 = np.array([3100000.0, 1000000.0, 5450000.0])
    from gpsins import _core
    llh = _core.ecef_to_geodetic(r0)
    g = _core.normal_gravity(llh[0], llh[2]) if hasattr(_core, "normal_gravity") else 9.81
    imu[:, 6] = -float(np.asarray(g).ravel()[-1]) * dt
    tf = np.arange(1.0, t[-1], 1.0)
    fixes = np.column_stack([tf, np.repeat(r0[None], len(tf), 0), np.full((len(tf), 3), np.nan),
                             np.full(len(tf), 1.0), np.full(len(tf), 1.5), np.full(len(tf), 2.0)])
    t0 = time.perf_counter()
    flt.run(imu, fixes, "default")
    return time.perf_counter() - t0


def main() -> None:
    full = "--pyubx2-full" in sys.argv
    with tempfile.TemporaryDirectory() as tmp:
        csv = Path(tmp) / "imu.csv"
        n = write_csv(csv)
        t0 = time.perf_counter()
        d = imu_csv.read(csv, ["t", "ax", "ay", "az", "gx", "gy", "gz"], "gpst_unix", "g", "rad/s")
        dt_csv = time.perf_counter() - t0
        print(f"IMU CSV, 1 h at 100 Hz: {n} rows, {csv.stat().st_size / 1e6:.1f} MB in {dt_csv:.2f} s "
              f"({n / dt_csv / 1e3:.0f} k rows/s), {len(d)} increments")

        walk = WALK_UBX.read_bytes()
        copies = int(np.ceil(3600.0 / 134.0))
        hour = Path(tmp) / "hour.ubx"
        hour.write_bytes(walk * copies)
        t0 = time.perf_counter()
        u = ubx.read(hour)
        dt_ubx = time.perf_counter() - t0
        frames = sum(v for k, v in u.counts.items() if k != "NMEA sentences")
        print(f"UBX, 1 h at 4 Hz ({copies} copies of the walk, {hour.stat().st_size / 1e6:.1f} MB): {frames} frames "
              f"({u.counts['RXM-RAWX']} RAWX, {u.counts['RXM-SFRBX']} SFRBX, {u.counts['NAV-PVT']} NAV-PVT) "
              f"in {dt_ubx:.2f} s ({frames / dt_ubx / 1e3:.0f} k frames/s)")

        import pyubx2
        data = hour if full else WALK_UBX
        t0 = time.perf_counter()
        with open(data, "rb") as f:
            k = sum(1 for _ in pyubx2.UBXReader(f, protfilter=pyubx2.UBX_PROTOCOL, quitonerror=0))
        dt_py = (time.perf_counter() - t0) * (1 if full else copies)
        print(f"pyubx2 {pyubx2.__version__}: {k} frames{'' if full else ' (one copy)'}; "
              f"{'measured' if full else 'scaled to the hour'}: {dt_py:.1f} s")

    dt_f = filter_hour()
    print(f"filter (loose, default preset), 1 h at 100 Hz with 1 Hz fixes: {dt_f:.2f} s")
    print(f"peak RSS {peak_mb():.0f} MB")


if __name__ == "__main__":
    main()
