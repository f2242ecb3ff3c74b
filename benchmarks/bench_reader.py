"""Record-file reader throughput and peak memory:

    python benchmarks/bench_reader.py [MB ...] [--block MB] [--cases scan,imu,decoded,whole]

Default sizes 120 and 250 MB (a 24-hour BP3010 log at 64 Hz is 24 h x 3600 x 64 x 24 B = 133 MB).
Writes a BP3010 record file of each size (valid records, a little garbage every
10,000 records so the resynchronisation path is exercised), then runs each case
in a fresh process, so peaks do not mix, and prints its wall and CPU time
(the CPU figure is steadier on a shared machine), MB/s and peak RSS
(VmHWM, see peak_rss_mb), also as a multiple of the file size, and the process's RSS before
reading (interpreter and imports):

- scan: `logs.read_record_file` (block by block; stamps, offsets, lengths, frame bytes kept)
- imu: scan, then `logs.imu_log` (int16 counts, 14 bytes a record on top)
- decoded: `logs.read_record_file(..., imu_rate_hz=64)`, replay's route: increments decoded
  block by block, no frames kept
- whole: the whole-buffer `logs.scan` of the file in memory, then `logs.imu_log` (what the
  reader did before it streamed; the reference the streaming reader is tested against)
"""

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CASES = ("scan", "imu", "decoded", "whole")


def make_file(path: Path, megabytes: float) -> int:
    from gpsins_logger import bp3010
    from gpsins_logger.recorder import STAMP

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


def peak_rss_mb() -> float:
    """This process's peak RSS: VmHWM, which starts afresh at exec; ru_maxrss keeps the
    peak of the process that forked us (Linux), so a big parent would mask the figure."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024 / 1e6
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e6


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 1e6


def run_case(case: str, path: Path, block_mb: float) -> dict:
    from gpsins.session import logs
    from gpsins.session import stamps
    from gpsins.session import scan as log_scan
    from gpsins.session import layouts

    block = int(block_mb * 2**20)
    before = rss_mb()
    t, cpu = time.perf_counter(), time.process_time()
    if case == "scan":
        n = logs.read_record_file(path, "bp3010", block_bytes=block).count
    elif case == "imu":
        n = len(logs.imu_log(logs.read_record_file(path, "bp3010", block_bytes=block)))
    elif case == "decoded":
        n = len(logs.imu_log(logs.read_record_file(path, "bp3010", block_bytes=block, imu_rate_hz=64)))
    elif case == "whole":
        limits = stamps.StampLimits()
        scanned = log_scan.scan(np.fromfile(path, np.uint8), layouts.BP_RECORDS, str(path), limits)
        s = stamps.reject_bad_stamps(scanned, limits)
        n = len(logs.imu_log(s))
    else:
        raise SystemExit(f"unknown case {case!r} (one of {', '.join(CASES)})")
    dt, cpu = time.perf_counter() - t, time.process_time() - cpu
    peak = peak_rss_mb()
    return {"records": n, "seconds": dt, "cpu_s": cpu, "peak_mb": peak, "before_mb": before}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("sizes", nargs="*", type=float, default=[120.0, 250.0])
    ap.add_argument("--block", type=float, default=4.0, help="read block, MiB")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--case", help=argparse.SUPPRESS)
    ap.add_argument("--file", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.case:
        print(json.dumps(run_case(a.case, Path(a.file), a.block)))
        return
    print(f"block {a.block:g} MiB; MB = 1e6 bytes; peak RSS is the whole process "
          "(the 'before' column: interpreter and imports)")
    print(f"{'case':>8} {'MB':>6} {'records':>9} {'wall s':>7} {'MB/s':>6} {'cpu s':>6} {'MB/cpu s':>8} "
          f"{'peak MB':>8} {'x file':>7} {'before':>7}")
    with tempfile.TemporaryDirectory() as d:
        for mb in a.sizes:
            path = Path(d) / "imu-000.bin"
            records = make_file(path, mb)
            size = path.stat().st_size / 1e6
            for case in a.cases.split(","):
                out = subprocess.run([sys.executable, __file__, "--case", case, "--file", str(path), "--block",
                                      str(a.block)], capture_output=True, text=True, check=True)
                r = json.loads(out.stdout.strip().splitlines()[-1])
                assert r["records"] == records, (case, r["records"], records)
                print(f"{case:>8} {size:6.0f} {records:9d} {r['seconds']:7.2f} {size / r['seconds']:6.0f} "
                      f"{r['cpu_s']:6.2f} {size / r['cpu_s']:8.0f} "
                      f"{r['peak_mb']:8.0f} {r['peak_mb'] / size:7.2f} {r['before_mb']:7.0f}",
                      flush=True)
            path.unlink()


if __name__ == "__main__":
    main()
