"""Simulator speed and memory per profile and IMU rate: what `gpsins sim` does.

    python benchmarks/bench_sim.py                         # the default drive and the 43-minute one, 64 Hz
    python benchmarks/bench_sim.py --day                   # ... and the 24-hour drive (takes long)
    python benchmarks/bench_sim.py default walk long --rates 64,400 --block-s 30
    python benchmarks/bench_sim.py long --whole            # the in-memory path (simulate + write_session)

Each (profile, rate) runs in a fresh process, so its peak RSS is its own. The
default path simulates and writes the session block by block (truth at the
internal rate near 1 kHz, IMU errors, receiver epochs and fixes, the reference,
the encoded frames and the truth file), so the peak grows with the block, not
the drive. Target: the 24-hour drive at 64 Hz within 1.5 GB peak.
"cpu s" is the process's user + system time (wall time suffers on a shared
machine); "s per h" is wall seconds per hour of drive.
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
from gpsins.sim import scenario
from gpsins.sim.scenario import with_imu_rate
from gpsins.sim.session import simulate_session, write_session

DEFAULT_PROFILES = ["default", "long"]


def one(name: str, rate: int | None, seed: int, block_s: float, whole: bool, out_dir: str | None) -> dict:
    sc = scenario.load(name)
    if rate:
        sc = with_imu_rate(sc, rate)
    with tempfile.TemporaryDirectory(dir=out_dir) as d:
        t0 = time.perf_counter()
        if whole:
            write_session(sim.simulate(sc, seed), Path(d) / "s")
        else:
            simulate_session(sc, seed, Path(d) / "s", block_s)
        wall = time.perf_counter() - t0
        files = {p.name: p.stat().st_size / 1e6 for p in (Path(d) / "s").iterdir()}
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return {"profile": sc.name, "rate_hz": sc.imu.rate_hz, "duration_s": sc.duration_s, "wall_s": wall,
            "cpu_s": ru.ru_utime + ru.ru_stime,
            "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "session_mb": sum(v for k, v in files.items() if k != "truth.npz"), "truth_mb": files["truth.npz"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("profiles", nargs="*", default=None)
    ap.add_argument("--rates", default="", help="IMU rates, comma-separated (default: the scenario's)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--block-s", type=float, default=sim.DEFAULT_BLOCK_S, help="block length (default %(default)s s)")
    ap.add_argument("--whole", action="store_true", help="the in-memory path: simulate() then write_session()")
    ap.add_argument("--day", action="store_true",
                    help="add the 24-hour drive (scenario long_24h; about 2.9 GB of files)")
    ap.add_argument("--out-dir", help="where the temporary session goes (default: the system's temporary directory)")
    ap.add_argument("--one", action="store_true", help=argparse.SUPPRESS)  # child: one profile, JSON out
    a = ap.parse_args()
    rates = [int(r) for r in a.rates.split(",") if r] or [0]
    profiles = a.profiles or DEFAULT_PROFILES + (["long_24h"] if a.day else [])
    if a.one:
        print(json.dumps(one(profiles[0], rates[0], a.seed, a.block_s, a.whole, a.out_dir)))
        return
    how = "in memory" if a.whole else f"in blocks of {a.block_s:g} s"
    print(f"gpsins sim {how}, seed {a.seed}")
    print(f"{'profile':<15}{'rate':>5}{'drive s':>9}{'wall s':>9}{'cpu s':>8}{'s per h':>9}{'peak MB':>9}"
          f"{'session MB':>12}{'truth MB':>10}")
    for name in profiles:
        for r in rates:
            cmd = [sys.executable, __file__, name, "--one", "--seed", str(a.seed), "--block-s", str(a.block_s)]
            cmd += (["--rates", str(r)] if r else []) + (["--whole"] if a.whole else [])
            cmd += ["--out-dir", a.out_dir] if a.out_dir else []
            out = subprocess.run(cmd, capture_output=True, text=True)
            if out.returncode:
                print(f"{name}: failed\n{out.stderr}", file=sys.stderr)
                continue
            x = json.loads(out.stdout.splitlines()[-1])
            print(f"{x['profile']:<15}{x['rate_hz']:>5}{x['duration_s']:>9.0f}{x['wall_s']:>9.1f}{x['cpu_s']:>8.1f}"
                  f"{x['wall_s'] / x['duration_s'] * 3600:>9.0f}{x['peak_mb']:>9.0f}{x['session_mb']:>12.1f}"
                  f"{x['truth_mb']:>10.1f}", flush=True)


if __name__ == "__main__":
    main()
