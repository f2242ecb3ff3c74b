"""gpsins live beside the real logger daemon on an emulated drive at real time: its CPU share, and how
long after the logger stamped an epoch's GNSS messages the NMEA sentence for that epoch left (p50, p99,
max), measured two ways: from the epoch's measurement block (ID 23, the epoch's first message) and from
the epoch's last GNSS message (the issue's measure: the first byte of the last record the receiver sent
for that epoch, ID 49 after the fix ID 20/21). The sentence for a fix epoch is the one for the last IMU
epoch at or before the fix's time: live sends it as soon as the fix is in (the samples after it wait
for the next fix). Prints figures; asserts nothing about them.

    python benchmarks/bench_live.py [DRIVE_S] [INTERVAL_S] [FIX_RATE_HZ]

Measured as a separate `gpsins live` process (as on the vehicle), its CPU from its rusage. The IMU is
the BP3010's at 64 Hz, its highest rate (the logger commands one of 64/32/16/8 Hz); the GNSS sends a
measurement block every 0.1 s and a fix at FIX_RATE_HZ (the Superstar II's 1 Hz by default, 10 for a
10 Hz GNSS).
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

from gpsins.session import logs, measurements
from gpsins import mainjob, sim
from gpsins.replay import run, results
from gpsins.live import outputs
from gpsins.sim.scenario import parse
from gpsins_logger import superstar2 as ss2

START = {"gps_week": 1590, "gps_tow_s": 419400.0, "lat_deg": 59.37, "lon_deg": 17.95, "height_m": 30.0,
         "heading_deg": 160.0}


def epoch_stamps(session: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per measurement block: its time of week, its stamp, and the stamp of the epoch's last GPS record
    (the last before the next block)."""
    files = logs.read_session(session).sensors["gps"]
    tow, first, last = [], [], []
    for fr, st in files.iter_frames():
        try:
            msg_id, payload = ss2.decode_frame(fr)
        except ss2.ProtocolError:
            continue
        if msg_id == ss2.ID_MEASUREMENTS:
            tow.append(ss2.Measurements.decode(payload).tow_s)
            first.append(st)
            last.append(st)
        elif last:
            last[-1] = st
    return np.round(np.array(tow), 1), np.array(first), np.array(last)


def main(drive_s: float = 60.0, interval_s: float = 0.02, fix_rate_hz: float = 1.0) -> None:
    root = Path(tempfile.mkdtemp(prefix="bench_live_"))
    sc = parse({"name": "bench", "start": START, "gnss": {"fix_rate_hz": int(fix_rate_hz)}, "segment": [
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
                    c.settimeout(None)
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
    tow, first, last = epoch_stamps(session)
    first_of, last_of = dict(zip(tow, first)), dict(zip(tow, last))
    # Sentences and epochs are one to one and in order (every epoch sent): live.f64 gives each sentence's
    # epoch time exactly (the sentence's own time is to 0.01 s).
    # The client may have connected after the first sentences: the first it got, by its time.
    epoch_t = outputs.read_epochs(root / "live" / "live.f64")["t"]
    leap = dec.gps.leap_s or 0
    h = arrivals[0][1].split(",")[1] if arrivals else "000000"
    tow0 = ((int(h[:2]) * 3600 + int(h[2:4]) * 60 + float(h[4:]) + leap) % 86400
            + (START["gps_tow_s"] // 86400) * 86400)
    j = int(np.argmin(np.abs(epoch_t - tow0)))
    n = min(len(epoch_t) - j, len(arrivals))
    epoch_t, sent_at = epoch_t[j:j + n], np.array([a for a, _ in arrivals[:n]])
    after_first, after_last, fix_t = [], [], []
    for t_fix in np.round(dec.gps.fixes[:, 0], 1):
        k = np.searchsorted(epoch_t, t_fix + 1e-9) - 1  # the last IMU epoch at or before the fix
        if k < 0 or t_fix - epoch_t[k] > 0.05 or t_fix not in first_of:
            continue
        after_first.append(sent_at[k] - first_of[t_fix])
        after_last.append(sent_at[k] - last_of[t_fix])
        fix_t.append(t_fix)
    fix_t, after_first, after_last = np.array(fix_t), np.array(after_first), np.array(after_last)
    if os.environ.get("BENCH_LIVE_DUMP"):  # per fix epoch: time, delay after ID 23, after the last message
        np.savetxt(os.environ["BENCH_LIVE_DUMP"], np.column_stack([fix_t, after_first, after_last]))
    print(f"{drive_s:.0f} s drive at real time, fixes at {fix_rate_hz:g} Hz, IMU at {dec.imu.rate_hz} Hz, live "
          f"polling every {interval_s:g} s: CPU {100 * used / wall:.1f} % of a core ({used:.1f} s in {wall:.0f} s)")
    # The finished session replayed with the same configuration: the live solution against it.
    z = results.load(run.replay(session, root / "replay").out)
    e = outputs.read_epochs(root / "live" / "live.f64")
    if len(e["t"]) == len(z["t"]):
        dr = np.linalg.norm(e["r_ecef"] - z["r_ecef"], axis=1)
        dq = np.degrees(2 * np.arccos(np.clip(np.abs(np.sum(e["q_eb"] * z["q_eb"], axis=1)), 0, 1)))
        print(f"live against replay over {len(dr)} epochs: time max {1e3 * np.abs(e['t'] - z['t']).max():.3f} ms, "
              f"position max {1e3 * dr.max():.2f} mm (median {1e3 * np.median(dr):.2f}), "
              f"attitude max {dq.max():.5f} deg")
    else:
        print(f"live has {len(e['t'])} epochs, the replay {len(z['t'])}")
    for name, lat in (("the epoch's ID 23 stamp", after_first), ("the epoch's last GNSS message's stamp", after_last)):
        if len(lat):
            print(f"NMEA after {name}: p50 {1e3 * np.median(lat):.0f} ms, p99 {1e3 * np.percentile(lat, 99):.0f} ms, "
                  f"max {1e3 * lat.max():.0f} ms over {len(lat)} fix epochs")


if __name__ == "__main__":
    main(*(float(x) for x in sys.argv[1:4]))
