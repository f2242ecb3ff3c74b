"""The logger daemon: config, one thread per sensor, signals, session lifecycle.

    gpsins-logger --config logger.toml [--session-dir DIR] [--duration S]

SIGINT, SIGTERM and SIGTSTP stop it cleanly (threads joined, files fsynced
and closed, ports closed, sidecar completed); SIGHUP starts a new part.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
import time
from pathlib import Path

from . import __version__, config as config_mod
from .port import DEVICES, SensorThread
from .recorder import SensorInfo, Session, StartupError, new_session_dir

log = logging.getLogger("gpsins_logger")
# How often the session directory is looked at, at least (a deleted one is continued elsewhere).
DIRECTORY_CHECK_S = 1.0
HEADER_LEN = {device: header_len for device, (_, header_len) in DEVICES.items()}


class Daemon:
    def __init__(self, cfg: config_mod.LoggerConfig, session_dir: Path | None = None):
        self.cfg = cfg
        self._wake = threading.Event()
        self._stop_requested = False
        self._rotate_requested = False
        infos = {}
        settings_of = {}
        for name, sc in cfg.sensors().items():
            device = getattr(sc, "device", "superstar2") if name == "gps" else "bp3010"
            settings = {"port": sc.port, "baud": sc.baud}
            if device == "ublox":
                settings.update(generation=sc.generation, interface=sc.interface,
                                measurement_rate_hz=sc.measurement_rate_hz, messages=sc.messages)
            elif name == "gps":
                settings.update(link_open=sc.link_open, raw_rate_hz=sc.raw_rate_hz, messages=sc.messages)
            else:
                settings.update(rate_hz=sc.rate_hz)
            infos[name] = SensorInfo(device, HEADER_LEN[device], sc.raw_capture, settings)
            settings_of[name] = (device, sc)
        directory = session_dir or new_session_dir(Path(cfg.session.root))
        self.session = Session(directory, infos, config=_config_record(cfg),
                               fsync_interval_s=cfg.session.fsync_interval_s,
                               raw_reserve_bytes=int(cfg.session.raw_reserve_mb * 1e6))
        self.threads = [
            SensorThread(name, device, sc.port, sc.baud, sc.requests(), self.session, sc.raw_capture,
                         cfg.reconnect.initial_backoff_s, cfg.reconnect.max_backoff_s, cfg.reconnect.poll_interval_s,
                         cfg.reconnect.unopenable_retry_s, cfg.reconnect.give_up_after_s,
                         sc.setup() if device == "ublox" else None, cfg.reconnect.busy_poll_s)
            for name, (device, sc) in settings_of.items()
        ]

    def request_stop(self, *_args) -> None:
        self._stop_requested = True
        self._wake.set()

    def request_rotate(self, *_args) -> None:
        self._rotate_requested = True
        self._wake.set()

    def run(self, duration_s: float | None = None) -> int:
        log.info("session %s", self.session.directory)
        for t in self.threads:
            t.start()
        start = time.monotonic()
        next_clock = start + self.cfg.session.clock_pair_interval_s
        next_sync = start + self.cfg.session.fsync_interval_s
        try:
            while not self._stop_requested:
                now = time.monotonic()
                # The directory is checked at least every DIRECTORY_CHECK_S, whatever the fsync period.
                timeout = max(0.0, min(next_sync, next_clock, now + DIRECTORY_CHECK_S) - now)
                if duration_s is not None:
                    timeout = min(timeout, max(0.0, start + duration_s - now))
                self._wake.wait(timeout)
                self._wake.clear()
                now = time.monotonic()
                if duration_s is not None and now - start >= duration_s:
                    break
                rotated = self._rotate_requested
                if rotated:
                    self._rotate_requested = False
                    self.session.rotate()
                if now >= next_clock:
                    self.session.clock_pair()
                    next_clock = now + self.cfg.session.clock_pair_interval_s
                if now >= next_sync or rotated:
                    self.session.check_free_space()
                    self.session.sync()
                    self.session.write_sidecar()  # checks the directory first
                    next_sync = now + self.cfg.session.fsync_interval_s
                else:
                    self.session.check_directory()
        finally:
            self.shutdown()
        return 0

    def shutdown(self) -> None:
        for t in self.threads:
            t.stop()
        for t in self.threads:
            t.join(timeout=10.0)
            if t.is_alive():
                log.error("thread %s did not stop", t.name)
        self.session.close()
        counts = self.session.sidecar()["counts"]
        log.info("stopped; %s", ", ".join(f"{k}: {v['frames_written']} frames" for k, v in counts.items()))
        if not any(t.ever_opened for t in self.threads) and self.session.remove_if_empty():
            # E.g. a second logger started on devices another one holds: no empty session left per attempt.
            log.info("no device was ever opened: removed the empty session directory %s", self.session.directory)


def _config_record(cfg: config_mod.LoggerConfig) -> dict:
    out = {"source": cfg.source, "session": vars(cfg.session), "reconnect": vars(cfg.reconnect)}
    for name, sc in cfg.sensors().items():
        out[name] = vars(sc)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="gpsins-logger", description="Log the GPS receiver and the IMU to a session.")
    p.add_argument("--config", required=True, help="logger TOML file (see logger.example.toml)")
    p.add_argument("--session-dir", type=Path, help="create exactly this session directory")
    p.add_argument("--duration", type=float, help="stop by itself after this many seconds")
    p.add_argument("--log-level", default="INFO")
    p.add_argument("--version", action="version", version=f"gpsins-logger {__version__}")
    args = p.parse_args(argv)
    logging.basicConfig(level=args.log_level.upper(), format="%(levelname)s %(name)s: %(message)s",
                        stream=sys.stderr)
    try:
        cfg = config_mod.load(args.config)
    except config_mod.ConfigError as e:
        print(f"gpsins-logger: config error: {e}", file=sys.stderr)
        return 2
    try:
        daemon = Daemon(cfg, args.session_dir)
    except FileExistsError as e:
        print(f"gpsins-logger: session directory exists: {e.filename}", file=sys.stderr)
        return 2
    except StartupError as e:
        print(f"gpsins-logger: {e}", file=sys.stderr)
        return 2
    print(daemon.session.directory, flush=True)
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGTSTP):
        signal.signal(sig, daemon.request_stop)
    signal.signal(signal.SIGHUP, daemon.request_rotate)
    return daemon.run(args.duration)


if __name__ == "__main__":
    sys.exit(main())
