"""Reader speed on an hour of data: `python benchmarks/bench_readers.py [--pyubx2-full]`.

- IMU CSV: a synthetic 1-hour 100 Hz table laid out like the walk's (GPST Unix seconds,
  accelerometer in g, gyro in rad/s, four unused columns; 360,000 rows), read by
  ``readers.imu_csv`` (rates to increments included).
- UBX: the walk's 134 s capture (RAWX, SFRBX, NAV-PVT and NMEA at 4 Hz) repeated to an
  hour (27 copies), read by ``readers.ubx``; pyubx2 on one copy for comparison, scaled to
  the hour (``--pyubx2-full`` runs it on the whole hour).
- The loosely coupled filter on an hour at 100 Hz (bench_filter's synthetic drive, 1 Hz
  fixes), the time the readers are measured against.

Prints wall-clock seconds (CPU seconds of this process in brackets: steadier on a busy
machine), rows or frames per second and peak RSS.
"""

import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gpsins.nav import runs as flt
from gpsins.formats import imu_csv, ubx

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


class Clock:
    def __enter__(self):
        self.wall, self.cpu = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc):
        self.wall, self.cpu = time.perf_counter() - self.wall, time.process_time() - self.cpu

    def __str__(self):
        return f"{self.wall:.2f} s ({self.cpu:.2f} s CPU)"


def filter_hour() -> "Clock":
    """The loose filter over bench_filter's synthetic drive (turning at 10 m/s, 1 Hz fixes), 1 h at 100 Hz."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_filter import synthetic

    imu, fixes = synthetic(360_000)
    with Clock() as c:
        flt.run(imu, fixes, "default")
    return c


def main() -> None:
    full = "--pyubx2-full" in sys.argv
    with tempfile.TemporaryDirectory() as tmp:
        csv = Path(tmp) / "imu.csv"
        n = write_csv(csv)
        with Clock() as c:
            d = imu_csv.read(csv, ["t", "ax", "ay", "az", "gx", "gy", "gz"], "gpst_unix", "g", "rad/s")
        print(f"IMU CSV, 1 h at 100 Hz: {n} rows, {csv.stat().st_size / 1e6:.1f} MB in {c} "
              f"({n / c.wall / 1e3:.0f} k rows/s), {len(d)} increments")

        walk = WALK_UBX.read_bytes()
        copies = int(np.ceil(3600.0 / 134.0))
        hour = Path(tmp) / "hour.ubx"
        hour.write_bytes(walk * copies)
        with Clock() as c:
            u = ubx.read(hour)
        frames = sum(v for k, v in u.counts.items() if k != "NMEA sentences")
        print(f"UBX, 1 h at 4 Hz ({copies} copies of the walk, {hour.stat().st_size / 1e6:.1f} MB): {frames} frames "
              f"({u.counts['RXM-RAWX']} RAWX, {u.counts['RXM-SFRBX']} SFRBX, {u.counts['NAV-PVT']} NAV-PVT) "
              f"in {c} ({frames / c.wall / 1e3:.0f} k frames/s)")

        import pyubx2
        data = hour if full else WALK_UBX
        with Clock() as c, open(data, "rb") as f:
            k = sum(1 for _ in pyubx2.UBXReader(f, protfilter=pyubx2.UBX_PROTOCOL, quitonerror=0))
        scale = 1 if full else copies
        print(f"pyubx2 {pyubx2.__version__}: {k} frames{'' if full else ' (one copy)'}; "
              f"{'measured' if full else 'scaled to the hour'}: {c.wall * scale:.1f} s ({c.cpu * scale:.1f} s CPU)")

    print(f"filter (loose, default preset), 360,000 IMU epochs (1 h at 100 Hz) with 1 Hz fixes: {filter_hour()}")
    print(f"peak RSS {peak_mb():.0f} MB")


if __name__ == "__main__":
    main()
