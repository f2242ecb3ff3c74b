"""Logger configuration (TOML), validated in full before anything is opened.

Example: logger/logger.example.toml. Every error names the key.
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from . import bp3010, superstar2, ubx

STANDARD_BAUDS = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600)


class ConfigError(ValueError):
    """An invalid configuration; the message names the file and key."""


@dataclass
class GpsConfig:
    port: str
    baud: int = 115200
    link_open: bool = True
    raw_rate_hz: int = 10  # ID 23 rate; 0 = not requested
    messages: list[int] = field(default_factory=lambda: [20, 21, 22, 49, 75, 113])
    raw_capture: bool = False

    def requests(self) -> list[bytes]:
        """The initialisation the GPS thread sends after every (re)open."""
        out = [superstar2.request_link_open()] if self.link_open else []
        if self.raw_rate_hz:
            out.append(superstar2.request_raw_rate(self.raw_rate_hz))
        out += [superstar2.request_message(m, continuous=True) for m in self.messages]
        return out


@dataclass
class UbloxConfig:
    """[gps] with device = "ublox": a u-blox receiver speaking UBX."""

    port: str
    device: str = "ublox"
    baud: int = 115200
    generation: int = 9  # 9: CFG-VALSET (F9P, F9R); 8: CFG-RATE + CFG-MSG (M8T, NEO-M8L)
    interface: str = "uart1"  # the receiver's port the logger is wired to (generation 9 keys)
    measurement_rate_hz: float = 10.0
    messages: list[str] = field(default_factory=lambda: ["RXM-RAWX", "RXM-SFRBX", "NAV-PVT", "NAV-TIMEGPS"])
    ack_timeout_s: float = 1.0
    setup_retry_max_s: float = 10.0  # an unacknowledged set-up is sent again after 1 s, doubling up to this
    poll_version: bool = True
    raw_capture: bool = False

    def requests(self) -> list[bytes]:
        return []  # the set-up is a handshake (setup()), not fire-and-forget requests

    def setup(self) -> ubx.Setup:
        """The set-up handshake the GPS thread runs after every (re)open."""
        steps = ubx.setup_steps(self.generation, self.interface, self.measurement_rate_hz, self.messages)
        return ubx.Setup(steps, self.ack_timeout_s, self.poll_version, retry_max_s=self.setup_retry_max_s)


@dataclass
class ImuConfig:
    port: str
    baud: int = 38400
    rate_hz: int = 64
    raw_capture: bool = True  # the frame layout is assumed: keep the bytes too

    def requests(self) -> list[bytes]:
        return [bp3010.rate_command(self.rate_hz)]


@dataclass
class SessionConfig:
    root: str = "sessions"
    fsync_interval_s: float = 1.0
    clock_pair_interval_s: float = 10.0
    raw_reserve_mb: float = 50.0  # below this much free space the raw capture pauses first


@dataclass
class ReconnectConfig:
    initial_backoff_s: float = 0.2  # back-off for a port that fails right after opening
    max_backoff_s: float = 5.0
    poll_interval_s: float = 0.05  # how often an absent device's path is looked at
    unopenable_retry_s: float = 5.0  # retry period for a present device that cannot be opened
    busy_poll_s: float = 0.1  # ...but a busy (locked) one is tried this often: a handover loses no more
    give_up_after_s: float = 0.0  # stop trying an unopenable device after this long; 0 = never


@dataclass
class LoggerConfig:
    session: SessionConfig = field(default_factory=SessionConfig)
    reconnect: ReconnectConfig = field(default_factory=ReconnectConfig)
    gps: GpsConfig | UbloxConfig | None = None
    imu: ImuConfig | None = None
    source: str = "<defaults>"

    def sensors(self) -> dict[str, GpsConfig | UbloxConfig | ImuConfig]:
        return {name: cfg for name, cfg in (("gps", self.gps), ("imu", self.imu)) if cfg is not None}


_TYPES = {"port": str, "baud": int, "link_open": bool, "raw_rate_hz": int, "messages": list, "raw_capture": bool,
          "rate_hz": int, "root": str, "fsync_interval_s": (int, float), "clock_pair_interval_s": (int, float),
          "raw_reserve_mb": (int, float),
          "initial_backoff_s": (int, float), "max_backoff_s": (int, float), "poll_interval_s": (int, float),
          "unopenable_retry_s": (int, float), "busy_poll_s": (int, float), "give_up_after_s": (int, float),
          "device": str, "generation": int, "interface": str, "measurement_rate_hz": (int, float),
          "ack_timeout_s": (int, float), "setup_retry_max_s": (int, float), "poll_version": bool}


def _section(cls, data: dict, name: str, where: str):
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: [{name}] must be a table")
    known = set(cls.__dataclass_fields__)
    for key, value in data.items():
        if key not in known:
            raise ConfigError(f"{where}: unknown key '{name}.{key}' (known: {', '.join(sorted(known))})")
        want = _TYPES[key]
        if isinstance(value, bool) and want is not bool or not isinstance(value, want):
            raise ConfigError(f"{where}: '{name}.{key}' has the wrong type ({type(value).__name__})")
    try:
        return cls(**data)
    except TypeError as e:
        raise ConfigError(f"{where}: [{name}] {e}") from None


def _check_port(cfg, name: str, where: str, check_ports: bool) -> None:
    if cfg.baud not in STANDARD_BAUDS:
        raise ConfigError(f"{where}: '{name}.baud' = {cfg.baud} is not a standard rate {STANDARD_BAUDS}")
    if check_ports and not os.path.exists(cfg.port):
        raise ConfigError(f"{where}: '{name}.port' = {cfg.port!r} does not exist")


def from_dict(data: dict, where: str = "<config>", check_ports: bool = True) -> LoggerConfig:
    known = {"session", "reconnect", "gps", "imu"}
    for key in data:
        if key not in known:
            raise ConfigError(f"{where}: unknown section [{key}] (known: {', '.join(sorted(known))})")
    cfg = LoggerConfig(source=where)
    if "session" in data:
        cfg.session = _section(SessionConfig, data["session"], "session", where)
    if "reconnect" in data:
        cfg.reconnect = _section(ReconnectConfig, data["reconnect"], "reconnect", where)
    if "gps" in data and isinstance(data["gps"], dict) and data["gps"].get("device", "superstar2") != "superstar2":
        cfg.gps = _ublox(data["gps"], where, check_ports)
    elif "gps" in data:
        if "device" in data["gps"]:
            data = {**data, "gps": {k: v for k, v in data["gps"].items() if k != "device"}}
        cfg.gps = _section(GpsConfig, data["gps"], "gps", where)
        _check_port(cfg.gps, "gps", where, check_ports)
        if cfg.gps.raw_rate_hz and cfg.gps.raw_rate_hz not in superstar2.RAW_RATE_CODES:
            raise ConfigError(f"{where}: 'gps.raw_rate_hz' = {cfg.gps.raw_rate_hz} is not one of 0, "
                              f"{', '.join(map(str, superstar2.RAW_RATE_CODES))}")
        for m in cfg.gps.messages:
            if not isinstance(m, int) or not 0 < m < 128 or m == superstar2.ID_MEASUREMENTS:
                raise ConfigError(f"{where}: 'gps.messages' entry {m!r} is not a message ID 1..127 "
                                  "(ID 23 is set by gps.raw_rate_hz)")
    if "imu" in data:
        cfg.imu = _section(ImuConfig, data["imu"], "imu", where)
        _check_port(cfg.imu, "imu", where, check_ports)
        if cfg.imu.rate_hz not in bp3010.RATES_HZ:
            raise ConfigError(f"{where}: 'imu.rate_hz' = {cfg.imu.rate_hz} is not one of {bp3010.RATES_HZ}")
    if not cfg.sensors():
        raise ConfigError(f"{where}: configure at least one sensor ([gps] and/or [imu])")
    for key in ("fsync_interval_s", "clock_pair_interval_s"):
        if getattr(cfg.session, key) <= 0:
            raise ConfigError(f"{where}: 'session.{key}' must be positive")
    if cfg.session.raw_reserve_mb < 0:
        raise ConfigError(f"{where}: 'session.raw_reserve_mb' must be >= 0")
    if not 0 < cfg.reconnect.initial_backoff_s <= cfg.reconnect.max_backoff_s:
        raise ConfigError(f"{where}: need 0 < reconnect.initial_backoff_s <= reconnect.max_backoff_s")
    if not 0 < cfg.reconnect.poll_interval_s <= 1.0:
        raise ConfigError(f"{where}: 'reconnect.poll_interval_s' must be in (0, 1]")
    if cfg.reconnect.unopenable_retry_s <= 0:
        raise ConfigError(f"{where}: 'reconnect.unopenable_retry_s' must be positive")
    if not 0 < cfg.reconnect.busy_poll_s <= 10:
        raise ConfigError(f"{where}: 'reconnect.busy_poll_s' must be in (0, 10]")
    if cfg.reconnect.give_up_after_s < 0:
        raise ConfigError(f"{where}: 'reconnect.give_up_after_s' must be >= 0 (0 = never give up)")
    return cfg


def _ublox(data: dict, where: str, check_ports: bool) -> UbloxConfig:
    if data["device"] != "ublox":
        raise ConfigError(f"{where}: 'gps.device' = {data['device']!r} is not one of superstar2, ublox")
    gps = _section(UbloxConfig, data, "gps", where)
    _check_port(gps, "gps", where, check_ports)
    if gps.generation not in (8, 9):
        raise ConfigError(f"{where}: 'gps.generation' = {gps.generation} is not 8 or 9")
    if gps.interface not in ubx.INTERFACES:
        raise ConfigError(f"{where}: 'gps.interface' = {gps.interface!r} is not one of {', '.join(ubx.INTERFACES)}")
    if not 0.1 <= gps.measurement_rate_hz <= 25.0:
        raise ConfigError(f"{where}: 'gps.measurement_rate_hz' = {gps.measurement_rate_hz} is not in 0.1..25")
    for m in gps.messages:
        if m not in ubx.OUTPUT_MESSAGES:
            raise ConfigError(f"{where}: 'gps.messages' entry {m!r} is not one of {', '.join(ubx.OUTPUT_MESSAGES)}")
    if not 0 < gps.ack_timeout_s <= 30:
        raise ConfigError(f"{where}: 'gps.ack_timeout_s' must be in (0, 30]")
    if not 0 < gps.setup_retry_max_s <= 600:
        raise ConfigError(f"{where}: 'gps.setup_retry_max_s' must be in (0, 600]")
    return gps


def load(path: str | Path, check_ports: bool = True) -> LoggerConfig:
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such config file") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: not valid TOML: {e}") from None
    return from_dict(data, str(path), check_ports)
