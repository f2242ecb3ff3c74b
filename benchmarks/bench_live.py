"""gpsins live beside the real logger daemon on an emulated drive at real time: its CPU share, and how
long after the logger stamped an epoch's measurement block (ID 23: the first byte at the port) the NMEA
sentence for that epoch left (p50, p99, max).

    python benchmarks/bench_live.py [DRIVE_S] [INTERVAL_S]

Measured as a separate `gpsins live` process (as on the vehicle), its CPU from its rusage.
"""

import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from gpsins import measurements, mainjob, sim
from gpsins.sim.scenario import parse

START = {"gps_week": 1590, "gps_tow_s": 419400.0, "lat_deg": 59.37, "lon_deg": 17.95, "height_m": 30.0,
         "heading_deg": 160.0}


def main(drive_s: float = 60.0, interval_s: float = 1.0) -> None:
    root = Path(tempfile.mkdtemp(prefix="bench_live_"))
    sc = parse({"name": "bench", "start": START, "segment": [
        {"label": "stand", "duration_s": 20, "speed_mps": 0},
        {"label": "drive", "duration_s": drive_s - 20, "speed_mps": 10, "turn_deg": 90}]})
    s = sim.simulate(sc, seed=1)
    session = root / "session"
    port = 0
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    proc = subprocess.Popen([sys.executable, "-m", "gpsins.cli", "live", str(session), "--out", str(root / "live"),
                             "--nmea-port", str(port), "--interval", str(interval_s)], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    arrivals: list[tuple[float, str]] = []

    def listen():
        deadline = time.monotonic() + drive_s + 120
        while time.monotonic() < deadline:
            try:
                with socket.create_connection(("127.0.0.1", port), timeout=1.0) as c:
                    buf = b""
                    while True:
                        chunk = c.recv(65536)
                        if not chunk:
                            return
                        now = time.time()
                        buf += chunk
                        *lines, buf = buf.split(b"\r\n")
                        arrivals.extend((now, x.decode()) for x in lines if x.startswith(b"$GPGGA"))
            except OSError:
                time.sleep(0.1)

    th = threading.Thread(target=listen, daemon=True)
    th.start()
    t0 = time.monotonic()
    mainjob.record_drive(s, root, 1.0, session=session)
    _, _, usage = os.wait4(proc.pid, 0)  # the live process's own CPU (the daemon is another child)
    proc.returncode = 0
    wall = time.monotonic() - t0
    used = usage.ru_utime + usage.ru_stime
    th.join(5)
    dec = measurements.decode_session(session)
    stamp_of = dict(zip(np.round(dec.gps.tow, 1), dec.gps.stamps))
    leap = dec.gps.leap_s or 0
    lat = []
    for now, line in arrivals:
        hms = line.split(",")[1]
        sod = int(hms[:2]) * 3600 + int(hms[2:4]) * 60 + float(hms[4:])
        tow = round((sod + leap) % 86400 + (START["gps_tow_s"] // 86400) * 86400, 1)
        if abs(tow - round(tow)) < 1e-6 and tow in stamp_of:  # the fix epochs
            lat.append(now - stamp_of[tow])
    lat = np.array(lat)
    print(f"{drive_s:.0f} s drive at real time, live every {interval_s:g} s: CPU {100 * used / wall:.1f} % of a core "
          f"({used:.1f} s in {wall:.0f} s)")
    if len(lat):
        print(f"NMEA after the epoch's ID 23 stamp: p50 {1e3 * np.median(lat):.0f} ms, p99 "
              f"{1e3 * np.percentile(lat, 99):.0f} ms, max {1e3 * lat.max():.0f} ms over {len(lat)} epochs")


if __name__ == "__main__":
    main(*(float(x) for x in sys.argv[1:3]))
