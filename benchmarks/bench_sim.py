"""Simulator speed and memory per profile and IMU rate.

    python benchmarks/bench_sim.py                         # the default drive at 64 Hz
    python benchmarks/bench_sim.py default walk stop_and_go urban_highway long --rates 64,400

Each (profile, rate) runs in a fresh process, so its peak RSS is its own:
truth at the internal rate (near 1 kHz), IMU errors, receiver measurements
and fixes (simulate), then the session files (both devices' encoded frames
and the truth file). Target: the default drive under 10 s; the 1-hour
profile within a few GB.
"""

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from gpsins import sim
from gpsins.sim.scenario import with_imu_rate
from gpsins.sim.session import write_session


def one(name: str, rate: int | None, seed: int) -> dict:
    sc = sim.load(name)
    if rate:
        sc = with_imu_rate(sc, rate)
    t0 = time.perf_counter()
    s = sim.simulate(sc, seed)
    t1 = time.perf_counter()
    peak_sim = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    with tempfile.TemporaryDirectory() as d:
        write_session(s, Path(d) / "s")
        size = sum(p.stat().st_size for p in (Path(d) / "s").iterdir()) / 1e6
    t2 = time.perf_counter()
    return {"profile": sc.name, "rate_hz": sc.imu.rate_hz, "duration_s": sc.duration_s, "truth": len(s.truth),
            "imu": len(s.imu_t), "gnss": len(s.gnss.t), "simulate_s": t1 - t0, "files_s": t2 - t1,
            "peak_simulate_mb": peak_sim, "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "session_mb": size}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("profiles", nargs="*", default=["default"])
    ap.add_argument("--rates", default="", help="IMU rates, comma-separated (default: the scenario's)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--one", action="store_true", help=argparse.SUPPRESS)  # child: one profile, JSON out
    a = ap.parse_args()
    rates = [int(r) for r in a.rates.split(",") if r] or [0]
    if a.one:
        print(json.dumps(one(a.profiles[0], rates[0], a.seed)))
        return
    print(f"{'profile':<15}{'rate':>5}{'drive s':>9}{'truth':>10}{'IMU':>10}{'simulate s':>12}{'files s':>9}"
          f"{'peak MB':>9}{'session MB':>12}")
    for name in a.profiles:
        for r in rates:
            cmd = [sys.executable, __file__, name, "--one", "--seed", str(a.seed)] + (["--rates", str(r)] if r else [])
            out = subprocess.run(cmd, capture_output=True, text=True)
            if out.returncode:
                print(f"{name}: failed\n{out.stderr}", file=sys.stderr)
                continue
            x = json.loads(out.stdout.splitlines()[-1])
            print(f"{x['profile']:<15}{x['rate_hz']:>5}{x['duration_s']:>9.0f}{x['truth']:>10}{x['imu']:>10}"
                  f"{x['simulate_s']:>12.2f}{x['files_s']:>9.2f}{x['peak_mb']:>9.0f}{x['session_mb']:>12.1f}",
                  flush=True)


if __name__ == "__main__":
    main()
