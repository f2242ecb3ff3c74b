"""Record-file reader throughput: `python benchmarks/bench_reader.py [MB]` (default 120 MB).

Writes a BP3010 record file of the given size (valid records, a little garbage
every 10,000 records so the resynchronisation path is exercised), then times
`logs.read_record_file` + `logs.imu_log` on it. Prints MB/s and peak RSS.
"""

import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gpsins import logs
from gpsins_logger import bp3010
from gpsins_logger.recorder import STAMP


def make_file(path: Path, megabytes: float) -> int:
    rng = np.random.default_rng(0)
    frames = [bp3010.ImuSample(tuple(rng.normal(0, 1e-3, 3)), tuple(rng.normal(0, 1e-2, 3)), counter=k & 0xFF).encode()
              for k in range(256)]
    block = bytearray()
    for k in range(10_000):
        f = frames[k & 0xFF]
        block += f[:1] + STAMP.pack(1.7e9 + k / 64) + f[1:]
    block += b"\xa5\x00\x13"  # garbage
    n = int(megabytes * 1e6 // len(block)) + 1
    with open(path, "wb") as out:
        for _ in range(n):
            out.write(block)
    return n * 10_000


def main() -> None:
    mb = float(sys.argv[1]) if len(sys.argv) > 1 else 120.0
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "imu-000.bin"
        records = make_file(path, mb)
        size = path.stat().st_size
        t = time.perf_counter()
        s = logs.read_record_file(path, "bp3010")
        imu = logs.imu_log(s)
        dt = time.perf_counter() - t
    assert s.count == records and len(imu) == records, (s.count, records)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"{size / 1e6:.0f} MB, {records} records in {dt:.2f} s: {size / 1e6 / dt:.0f} MB/s, "
          f"{records / dt / 1e6:.2f} M records/s; peak RSS {peak:.0f} MB")


if __name__ == "__main__":
    main()
