"""Peak memory and time of decoding a long session for replay (`measurements.decode_session`):

    python benchmarks/bench_decode.py [HOURS ...]     (default 1)

Simulates the default drive (287 s) once, then writes a session of the given
length by repeating its record files with every stamp moved on by the drive's
span (the receiver's own times repeat, which the decoders take as they come:
the figure is about memory, not navigation). Each case runs in a fresh process
and prints its time and peak RSS (VmHWM, see bench_reader.peak_rss_mb):

- decode: `measurements.decode_session` (IMU decoded block by block, no frames kept)
- frames: `logs.read_session` with every frame kept, then `session.imu()`: the
  route decode_session took before, for comparison
"""

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_reader import peak_rss_mb  # the same VmHWM reading (this directory is on sys.path)


def repeat_session(src: Path, dst: Path, hours: float) -> dict:
    from gpsins.session import logs

    side = json.loads((src / "session.json").read_text())
    dst.mkdir()
    t0, t1 = side["start"]["realtime"], side["stop"]["realtime"]
    span = t1 - t0
    times = max(1, int(round(hours * 3600 / span)))
    sizes = {}
    for name, info in side["sensors"].items():
        for fname in info["files"]:
            s = logs.read_record_file(src / fname, info["device"])
            data = np.fromfile(src / fname, np.uint8)
            at = s.starts + s.layout.header_len
            with open(dst / fname, "wb") as out:
                for k in range(times):
                    stamped = data.copy()
                    rows = np.lib.stride_tricks.sliding_window_view(stamped, 8)[at].copy().view("<f8")[:, 0]
                    stamped[at[:, None] + np.arange(8)] = (rows + k * span).astype("<f8").view(np.uint8).reshape(-1, 8)
                    stamped.tofile(out)
            sizes[name] = (dst / fname).stat().st_size
    side["stop"]["realtime"] = t0 + times * span
    side["stop"]["monotonic"] = side["start"]["monotonic"] + times * span
    (dst / "session.json").write_text(json.dumps(side))
    (dst / "clock.csv").write_text("realtime,monotonic\n")
    return {"repeats": times, "hours": times * span / 3600, "bytes": sizes}


def run_case(case: str, session: Path) -> dict:
    from gpsins.session import logs, measurements

    t, cpu = time.perf_counter(), time.process_time()
    if case == "decode":
        dec = measurements.decode_session(session)
        n = len(dec.imu)
    elif case == "frames":
        n = len(logs.read_session(session).imu())
    else:
        raise SystemExit(f"unknown case {case!r}")
    return {"imu": n, "seconds": time.perf_counter() - t, "cpu_s": time.process_time() - cpu,
            "peak_mb": peak_rss_mb()}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("hours", nargs="*", type=float, default=[1.0])
    ap.add_argument("--cases", default="decode,frames")
    ap.add_argument("--case", help=argparse.SUPPRESS)
    ap.add_argument("--session", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.case:
        print(json.dumps(run_case(a.case, Path(a.session))))
        return
    from gpsins import sim
    from gpsins.sim import scenario
    from gpsins.sim.session import write_session

    with tempfile.TemporaryDirectory() as d:
        one = Path(d) / "one"
        write_session(sim.simulate(scenario.load("default"), seed=0), one)
        for hours in a.hours:
            long = Path(d) / f"long-{hours:g}"
            info = repeat_session(one, long, hours)
            files = ", ".join(f"{k} {v / 1e6:.0f} MB" for k, v in info["bytes"].items())
            print(f"{info['hours']:.2f} h ({info['repeats']} x the default drive): {files}")
            for case in a.cases.split(","):
                out = subprocess.run([sys.executable, __file__, "--case", case, "--session", str(long)],
                                     capture_output=True, text=True, check=True)
                r = json.loads(out.stdout.strip().splitlines()[-1])
                print(f"  {case:>7}: {r['imu']} IMU samples, {r['seconds']:.1f} s wall, {r['cpu_s']:.1f} s CPU, "
                      f"peak RSS {r['peak_mb']:.0f} MB", flush=True)
            for f in long.iterdir():
                f.unlink()
            long.rmdir()


if __name__ == "__main__":
    main()
