"""Simulator speed: `python benchmarks/bench_sim.py [SCENARIO] [SEED]`.

Times the default 287 s drive: truth at the internal rate (1024 Hz), IMU
errors, receiver measurements and fixes, then the session files (both
devices' encoded frames and the truth file). Target: under 10 s.
"""

import resource
import sys
import tempfile
import time
from pathlib import Path

from gpsins import sim
from gpsins.sim.session import write_session


def main() -> None:
    name = sys.argv[1] if len(sys.argv) > 1 else "default"
    seed = int(sys.argv[2]) if len(sys.argv) > 2 else 0
    sc = sim.load(name)
    t0 = time.perf_counter()
    s = sim.simulate(sc, seed)
    t1 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        write_session(s, Path(d) / "s")
    t2 = time.perf_counter()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"{sc.name}: {sc.duration_s:.0f} s drive, {len(s.truth)} truth samples, {len(s.imu_t)} IMU samples, "
          f"{len(s.gnss.t)} GNSS epochs; simulate {t1 - t0:.2f} s + session files {t2 - t1:.2f} s = "
          f"{t2 - t0:.2f} s; peak RSS {peak:.0f} MB")


if __name__ == "__main__":
    main()
