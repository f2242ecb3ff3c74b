"""Logger stamp latency and CPU: the real daemon against the pty emulators.

    python benchmarks/bench_logger.py [SECONDS] [SPEED]

Defaults: 60 s at real time (64 Hz IMU + 10 Hz ID 23 and the 1 Hz messages).
SPEED 10 replays ten times faster (a stress run). A soak is SECONDS=600.
Prints, per sensor, the stamp minus the emulator's first-byte realtime
(median, p99, max), the largest step back between consecutive stamps (0 since
the per-sensor clamp) and the daemon's CPU share. Run it beside two busy
loops (`python -c 'while 1: pass'`) to see stamps under load.
"""

import resource
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from ptyrig import run_rig  # noqa: E402


def main() -> None:
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 60.0
    speed = float(sys.argv[2]) if len(sys.argv) > 2 else 1.0
    with tempfile.TemporaryDirectory() as d:
        r = run_rig(Path(d), seconds=seconds, speed=speed)
        cpu = resource.getrusage(resource.RUSAGE_CHILDREN)
        assert r.returncode == 0, r.stderr
        wall = seconds / speed
        print(f"{seconds:.0f} s of data at speed {speed:g} ({wall:.0f} s wall)")
        for name, em in (("gps", r.emulators.gps), ("imu", r.emulators.imu)):
            ok = [s for s in em.sent if s.fate == "ok"]
            got = r.session.sensors[name].frames()
            lost = len(ok) - len(got)
            lat = (r.session.sensors[name].stamps - np.array([s.first_byte_realtime for s in ok])) * 1e3
            back = max(0.0, -float(np.diff(r.session.sensors[name].stamps).min(initial=0.0))) * 1e3
            print(f"  {name}: {len(got)} frames, {lost} lost; stamp - first byte: median {np.median(lat):.3f} ms, "
                  f"p99 {np.percentile(lat, 99):.3f} ms, max {lat.max():.3f} ms, min {lat.min():.3f} ms; "
                  f"largest backward step {back:.3f} ms")
        print(f"  daemon CPU {cpu.ru_utime + cpu.ru_stime:.2f} s = {100 * (cpu.ru_utime + cpu.ru_stime) / wall:.1f} % "
              f"of one core; peak RSS {cpu.ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
