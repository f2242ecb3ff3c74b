"""``gpsins dump``: what a session (or a raw device capture) holds.

The summary answers the first questions after a drive: how many records per
sensor and message, over which time span, at which rates, and what the reader
had to skip (with file offsets). ``--csv`` lists every record; ``--format
json`` gives the summary to programs.
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import numpy as np

from gpsins_logger import bp3010
from gpsins_logger import superstar2 as ss2

from . import logs
from . import layouts
from . import scan as log_scan


def _span(stamps: np.ndarray) -> dict:
    if len(stamps) == 0:
        return {"first": None, "last": None, "duration_s": 0.0}
    return {"first": float(stamps[0]), "last": float(stamps[-1]), "duration_s": float(stamps[-1] - stamps[0])}


def _gps_by_id(scans: list[layouts.Scan]) -> dict:
    out: dict[int, dict] = {}
    for s in scans:
        ids, st = layouts.message_ids(s), s.stamps
        for mid in np.unique(ids):
            sel = st[ids == mid]
            e = out.setdefault(int(mid), {"records": 0, "stamps": []})
            e["records"] += int(len(sel))
            e["stamps"].append(sel)
    result = {}
    for mid, e in sorted(out.items()):
        st = np.concatenate(e["stamps"])
        span = _span(st)
        rate = (len(st) - 1) / span["duration_s"] if span["duration_s"] > 0 else None
        result[str(mid)] = {"records": e["records"], "rate_hz": rate, **span}
    return result


def _imu_details(session: logs.SessionLog) -> dict:
    imu = session.imu()
    gaps = (np.diff(imu.counter.astype(np.int64)) - 1) % 256
    overrange = bp3010.STATUS_GYRO_OVERRANGE | bp3010.STATUS_ACCEL_OVERRANGE
    return {"rate_hz": imu.rate_hz, "invalid": int(np.count_nonzero((imu.status & bp3010.STATUS_VALID) == 0)),
            "overrange": int(np.count_nonzero(imu.status & overrange)),
            "missing_by_counter": int(gaps.sum())}


# Records this long past the sidecar's version (or 3 write periods, if longer) mean its writes were
# failing. Less is normal for a killed logger: on a loaded machine a rotation's fsyncs alone took 2.2 s.
SIDECAR_STALE_S = 10.0


def _sidecar_behind(sidecar: dict, last_stamp: float | None) -> dict | None:
    """Whether records go on past the sidecar's last version by more than its
    writes allow: then its state, counts and parts are older than the records
    (its writes failed, e.g. on a full disk, and the logger was then killed
    or never managed to write again)."""
    written = sidecar.get("written")
    if not isinstance(written, dict) or not isinstance(written.get("realtime"), (int, float)) or last_stamp is None:
        return None
    cfg = sidecar.get("config", {}).get("session", {}) if isinstance(sidecar.get("config"), dict) else {}
    period = cfg.get("fsync_interval_s", 1.0) if isinstance(cfg.get("fsync_interval_s"), (int, float)) else 1.0
    behind = last_stamp - float(written["realtime"])
    if behind <= max(SIDECAR_STALE_S, 3 * period):
        return None
    return {"written": float(written["realtime"]), "last_record": last_stamp, "behind_s": behind}


def session_summary(directory: str | Path) -> dict:
    session = logs.read_session(directory)
    out = {"session": str(session.directory), "sidecar": {k: session.sidecar.get(k) for k in
                                                          ("host", "state", "start", "stop", "written", "parts",
                                                           "continues", "continued_in")},
           "sensors": {}}
    lasts = [float(f.stamps[-1]) for f in session.sensors.values() if f.count]
    out["sidecar"]["older_than_records"] = _sidecar_behind(session.sidecar, max(lasts) if lasts else None)
    for name, files in session.sensors.items():
        entry = {"device": files.device, **files.stats(), **_span(files.stamps),
                 "damage": [{"file": Path(s.path).name, "first_discarded_offset": s.stats.get("first_discarded_offset"),
                             "truncated_tail_offset": s.stats.get("truncated_tail_offset"),
                             "first_bad_stamp_offset": s.stats.get("first_bad_stamp_offset")}
                            for s in files.scans
                            if s.stats.get("discarded_bytes") or s.stats.get("truncated_tail_bytes")]}
        if files.device == "superstar2":
            entry["messages"] = _gps_by_id(files.scans)
        elif files.device == "bp3010" and files.count:
            entry.update(_imu_details(session))
        out["sensors"][name] = entry
    return out


def raw_summary(path: str | Path, device: str) -> dict:
    """Frames in a raw device byte stream (a .raw capture or a plain byte dump)."""
    path = Path(path)
    if path.suffix == ".raw":  # a logger capture: per-read headers around the bytes
        stream = b"".join(chunk for _, _, chunk in logs.read_raw_capture(path))
    else:
        stream = path.read_bytes()
    if device == "superstar2":
        s = log_scan.scan(np.frombuffer(stream, np.uint8), layouts.SS2_RAW, str(path))
        ids = layouts.message_ids(s)
        messages = {str(int(m)): int(np.count_nonzero(ids == m)) for m in np.unique(ids)}
        return {"file": str(path), "device": device, "frames": s.count, "messages": messages, **s.stats}
    if device == "bp3010":
        from gpsins_logger.framing import FrameFinder

        finder = FrameFinder(bp3010.FRAMING)
        frames = finder.feed(stream) + finder.flush()
        st = finder.stats
        return {"file": str(path), "device": device, "frames": len(frames), "bytes": len(stream),
                "discarded_bytes": st.discarded_bytes, "checksum_failures": st.checksum_failures,
                "truncated_tail_bytes": st.tail_bytes, "truncated_tail_offset": st.tail_offset}
    raise layouts.LogError(f"{path}: unknown device {device!r} (superstar2 or bp3010)")


def write_csv(directory: str | Path, out) -> int:
    """One row per record: sensor, stamp, message id, length; IMU rows add the decoded increments."""
    session = logs.read_session(directory)
    w = csv.writer(out, lineterminator="\n")
    w.writerow(["sensor", "stamp_s", "msg_id", "frame_bytes", "counter", "status",
                "dtheta_x_rad", "dtheta_y_rad", "dtheta_z_rad", "dv_x_mps", "dv_y_mps", "dv_z_mps"])
    n = 0
    for name, files in session.sensors.items():
        if files.device == "bp3010":
            imu = session.imu()
            dtheta, dv = imu.dtheta_rad, imu.dv_mps
            for k in range(len(imu)):
                w.writerow([name, repr(float(imu.stamps[k])), "", bp3010.FRAME_LEN, int(imu.counter[k]),
                            int(imu.status[k]), *map(repr, dtheta[k].tolist()), *map(repr, dv[k].tolist())])
            n += len(imu)
            continue
        for s in files.scans:
            ids, st, lens = layouts.message_ids(s), s.stamps, s.lengths - layouts.STAMP_BYTES
            for k in range(s.count):
                w.writerow([name, repr(float(st[k])), int(ids[k]), int(lens[k])] + [""] * 8)
            n += s.count
    return n


def print_summary(summary: dict, out) -> None:
    if "sensors" not in summary:
        for k, v in summary.items():
            print(f"{k:>22}: {v}", file=out)
        return
    print(f"session {summary['session']}", file=out)
    side = summary.get("sidecar", {})
    c = side.get("continues")
    if isinstance(c, dict):
        carried = c.get("frames_carried_over") or {}
        print(f"  continues session {c.get('previous')}: {c.get('reason')}; carried over: "
              + (", ".join(f"{k} {v} records" for k, v in carried.items()) if any(carried.values())
                 else str(c.get("carried_over"))), file=out)
    if side.get("continued_in"):
        print(f"  continued in {side['continued_in']} (this directory lost files while logging)", file=out)
    if side.get("older_than_records"):
        print(f"  the sidecar is older than the records: last written {side['older_than_records']['behind_s']:.1f} s "
              f"before the last record (state '{side.get('state')}'); its counts, parts and state are from then "
              "(its writes failed, e.g. on a full disk)", file=out)
    for name, e in summary["sensors"].items():
        print(f"  {name} ({e['device']}): {e['records']} records, {e['bytes']} bytes, "
              f"{e['duration_s']:.1f} s; discarded {e['discarded_bytes']} bytes, "
              f"truncated tail {e['truncated_tail_bytes']} bytes, stamps backwards {e['stamps_backwards']}"
              + (" (records stamped earlier than the one before: the system clock was stepped back, or bytes came"
                 " faster than the port's baud rate, e.g. from an emulator above real time, so back-dating by byte"
                 " time overshot; replay's robust timing follows the earliest stamps and splits only at steps over"
                 " 20 ms)" if e["stamps_backwards"] else ""), file=out)
        for d in e["damage"]:
            print(f"    damage in {d['file']}: first discarded byte at {d['first_discarded_offset']}, "
                  f"truncated tail at {d['truncated_tail_offset']}", file=out)
        for mid, m in e.get("messages", {}).items():
            rate = f"{m['rate_hz']:.2f} Hz" if m["rate_hz"] else "-"
            label = ss2.MESSAGE_NAMES.get(int(mid), "?")
            print(f"    ID {mid:>3} {label:<22} {m['records']:>7} records  {rate}", file=out)
        if "rate_hz" in e:
            print(f"    {e['rate_hz']} Hz; invalid {e['invalid']}, over-range {e['overrange']}, "
                  f"missing by counter {e['missing_by_counter']}", file=out)


def main(args) -> int:
    # A missing or unreadable file raises LogError or OSError: gpsins.cli prints it as one line, exit 2.
    if args.raw:
        summary = raw_summary(args.path, args.raw)
    elif args.csv:
        write_csv(args.path, sys.stdout)
        return 0
    else:
        summary = session_summary(args.path)
    if args.format == "json":
        json.dump(summary, sys.stdout, indent=2)
        print()
    else:
        print_summary(summary, sys.stdout)
    return 0
