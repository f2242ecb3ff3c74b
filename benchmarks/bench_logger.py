"""Logger stamp latency and CPU: the real daemon against the pty emulators.

    python benchmarks/bench_logger.py [SECONDS] [SPEED] [--with-live]

Defaults: 60 s at real time (64 Hz IMU + 10 Hz ID 23 and the 1 Hz messages).
SPEED 10 replays ten times faster (a stress run). A soak is SECONDS=600.
Prints, per sensor, the stamp minus the emulator's first-byte realtime
(median, p99, max), the largest step back between consecutive stamps (0 since
the per-sensor clamp) and the daemon's CPU share. Run it beside two busy
loops (`python -c 'while 1: pass'`) to see stamps under load.

--with-live runs the same twice, alone and then with `gpsins live` following the
session as it is written (a separate process, as on the vehicle), so the logger's
figures with live beside it stand next to those without; live's own CPU is shown
apart and not counted in the daemon's.
"""

import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from ptyrig import run_rig  # noqa: E402


def _children_cpu() -> float:
    u = resource.getrusage(resource.RUSAGE_CHILDREN)
    return u.ru_utime + u.ru_stime


def measure(seconds: float, speed: float, with_live: bool) -> None:
    with tempfile.TemporaryDirectory() as d:
        live = {}

        def start_live(_emulators):
            # Started before the daemon: it waits for the session to appear, as the systemd unit does.
            env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
            live["proc"] = subprocess.Popen([sys.executable, "-m", "gpsins.cli", "live", str(Path(d) / "session"),
                                             "--out", str(Path(d) / "live")], env=env,
                                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

        cpu0 = _children_cpu()
        r = run_rig(Path(d), seconds=seconds, speed=speed, before=start_live if with_live else None)
        assert r.returncode == 0, r.stderr
        live_cpu = 0.0
        if with_live:
            p = live["proc"]
            try:
                _, _, usage = os.wait4(p.pid, 0)  # it ends once the session is stopped
            finally:
                p.returncode = 0
            live_cpu = usage.ru_utime + usage.ru_stime
        daemon_cpu = _children_cpu() - cpu0 - live_cpu
        wall = seconds / speed
        print(f"{seconds:.0f} s of data at speed {speed:g} ({wall:.0f} s wall), "
              f"{'with gpsins live beside the logger' if with_live else 'the logger alone'}")
        for name, em in (("gps", r.emulators.gps), ("imu", r.emulators.imu)):
            ok = [s for s in em.sent if s.fate == "ok"]
            got = r.session.sensors[name].frames()
            lost = len(ok) - len(got)
            lat = (r.session.sensors[name].stamps - np.array([s.first_byte_realtime for s in ok])) * 1e3
            back = max(0.0, -float(np.diff(r.session.sensors[name].stamps).min(initial=0.0))) * 1e3
            print(f"  {name}: {len(got)} frames, {lost} lost; stamp - first byte: median {np.median(lat):.3f} ms, "
                  f"p99 {np.percentile(lat, 99):.3f} ms, max {lat.max():.3f} ms, min {lat.min():.3f} ms; "
                  f"largest backward step {back:.3f} ms")
        print(f"  daemon CPU {daemon_cpu:.2f} s = {100 * daemon_cpu / wall:.1f} % of one core")
        if with_live:
            print(f"  gpsins live CPU {live_cpu:.2f} s = {100 * live_cpu / wall:.1f} % of one core (imports included)")


def main() -> None:
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    seconds = float(args[0]) if args else 60.0
    speed = float(args[1]) if len(args) > 1 else 1.0
    measure(seconds, speed, with_live=False)
    if "--with-live" in sys.argv:
        measure(seconds, speed, with_live=True)


if __name__ == "__main__":
    main()
