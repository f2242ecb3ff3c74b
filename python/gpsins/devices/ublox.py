"""A u-blox receiver on a pty (UBX: configuration, RAWX, SFRBX, NAV-PVT, ESF), with a BP3010 beside it
when asked; ``gpsins emulate --ublox``.
"""

from __future__ import annotations

import struct
import time
from pathlib import Path


from gpsins_logger import ubx
from gpsins_logger.framing import FrameFinder

from ..formats.messages import MessageSource
from .pty import Faults
from .emulate import DeviceEmulator, Emulators, ImuEmulator, serve_until_signalled


class UbloxEmulator(DeviceEmulator):
    """A u-blox receiver on a pty: answers CFG-VALSET (and generation 8's
    CFG-RATE / CFG-MSG) with ACK-ACK and MON-VER polls with its version, then
    sends the UBX messages the host enabled (RXM-RAWX decimated to the set
    measurement rate), and NMEA GGA throughout as a receiver does by default.
    ``config_fault``: "nak" refuses every configuration message, "silent"
    answers nothing (both leave the receiver unconfigured). With a recorded
    capture as the source (``serve_all``), every frame and sentence of the
    capture is served as recorded, whatever the host configured."""

    device = "ublox"
    SOFTWARE = "EXT CORE 1.00 (emulated)"
    HARDWARE = "00190000"

    def __init__(self, link: Path, source, baud: int = 115200, config_fault: str | None = None,
                 serve_all: bool = False, **kw):
        super().__init__(link, source, baud, **kw)
        if config_fault not in (None, "nak", "silent"):
            raise ValueError(f"config_fault must be None, 'nak' or 'silent', got {config_fault!r}")
        self.config_fault = config_fault
        self.serve_all = serve_all
        self._finder = FrameFinder(ubx.FRAMING)
        self._replies: list[bytes] = []
        self.enabled: set[str] = set()
        self.meas_rate_hz: float | None = None
        self.config_log: list[tuple[str, str]] = []  # (message, answer)

    def on_host_bytes(self, data: bytes) -> None:
        for frame in self._finder.feed(data):
            self.host_requests.append(frame.data)
            try:
                cls_id, payload = ubx.decode_frame(frame.data)
            except ubx.ProtocolError:
                continue
            if cls_id == ubx.MON_VER and not payload:
                if self.config_fault != "silent":
                    ver = self.SOFTWARE.encode().ljust(30, b"\0") + self.HARDWARE.encode().ljust(10, b"\0")
                    ver += b"PROTVER=27.11".ljust(30, b"\0")
                    self._replies.append(ubx.encode_frame(ubx.MON_VER, ver))
                continue
            if cls_id not in (ubx.CFG_VALSET, ubx.CFG_RATE, ubx.CFG_MSG):
                continue
            answer = self._configure(cls_id, payload) if self.config_fault is None else self.config_fault
            self.config_log.append((ubx.name_of(cls_id), answer))
            if answer != "silent":
                self._replies.append(ubx.encode_frame(ubx.ACK_ACK if answer == "ack" else ubx.ACK_NAK,
                                                      bytes(cls_id)))

    def _configure(self, cls_id, payload: bytes) -> str:
        try:
            if cls_id == ubx.CFG_VALSET:
                _, items = ubx.parse_valset(payload)
                msgout = {k: m for m, ports in ubx.MSGOUT_KEYS.items() for k in ports.values()}
                for key, value in items:
                    if key == ubx.CFG_RATE_MEAS:
                        self.meas_rate_hz = 1000.0 / value
                    elif key in msgout:
                        (self.enabled.add if value else self.enabled.discard)(msgout[key])
                    elif key not in ubx.KEY_NAMES:
                        return "nak"  # a key this receiver does not know: the whole set is refused
            elif cls_id == ubx.CFG_RATE:
                self.meas_rate_hz = 1000.0 / struct.unpack_from("<H", payload)[0]
            else:
                name = ubx.name_of((payload[0], payload[1]))
                (self.enabled.add if payload[2] else self.enabled.discard)(name)
        except (ubx.ProtocolError, struct.error, IndexError, ZeroDivisionError):
            return "nak"
        return "ack"

    def on_disconnect(self) -> None:
        # A replug powers the receiver down: the RAM configuration is gone.
        self.enabled.clear()
        self.meas_rate_hz = None
        self._replies.clear()
        self._finder = FrameFinder(ubx.FRAMING)

    def _wanted(self, m) -> bool:
        if self.serve_all or m.msg_id == "NMEA":
            return True
        if m.msg_id not in self.enabled:
            return False
        if m.msg_id == "RXM-RAWX" and self.meas_rate_hz:
            x = m.tow_s * self.meas_rate_hz
            return abs(x - round(x)) < 1e-6
        return True

    def _flush_replies(self) -> None:
        while self._replies:
            self.send_frame(self._replies.pop(0), self.run_time())

    def _wait_until(self, mono: float) -> bool:
        # Answers go out as soon as the line is free, between the messages.
        while True:
            if not super()._wait_until(min(mono, time.monotonic() + 0.02)):
                return False
            if self._replies and self._inflight is None:
                self._flush_replies()
            if time.monotonic() >= mono:
                return True

    def stream(self) -> None:
        if self.serve_all:
            # A capture is served from its start once the host listens (its first poll or
            # configuration message), so nothing of it is lost to a late open.
            while not self.host_requests:
                if not self._wait_until(time.monotonic() + 0.02):
                    return
            self._start_mono = self._line_free = time.monotonic()
        for m in self.source.gps_messages():
            if not self._wait_until(self._mono_at(m.t)):
                return
            if self._wanted(m):
                self.send_frame(m.frame, m.t)
        # Keep answering the host until stopped, as a powered receiver does.
        self.done.set()
        while self._wait_until(time.monotonic() + 0.05):
            pass


class UbloxEmulators(Emulators):
    """A u-blox receiver at <dir>/gps; with ``bp3010`` also a BP3010 at <dir>/imu
    (for a receiver without sensors), else the receiver's own ESF-RAW is the IMU."""

    def __init__(self, directory: Path, source: MessageSource, speed: float = 1.0, gps_faults: Faults | None = None,
                 imu_faults: Faults | None = None, gps_baud: int = 460800, imu_baud: int = 38400,
                 bp3010: bool = False, config_fault: str | None = None, serve_all: bool = False):
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        # A capture goes out in bigger chunks: it is dense, and served faster than real time.
        self.gps = UbloxEmulator(directory / "gps", source, gps_baud, config_fault=config_fault, serve_all=serve_all,
                                 speed=speed, faults=gps_faults, chunk_bytes=256 if serve_all else 16)
        self.imu = ImuEmulator(directory / "imu", source, imu_baud, speed=speed, faults=imu_faults) if bp3010 else None

    @property
    def devices(self) -> list[DeviceEmulator]:
        return [d for d in (self.gps, self.imu) if d is not None]


def run_ublox(args) -> int:
    """`gpsins emulate --device ublox`: a simulated F9R-like receiver, or a recorded UBX capture (--ubx)."""
    import sys

    if args.ubx:
        from .sources import UbxCaptureSource

        source, what = UbxCaptureSource(args.ubx), f"UBX capture {args.ubx}"
    elif args.session:
        print("gpsins emulate: --session serves a Superstar II session; give a UBX capture with --ubx",
              file=sys.stderr)
        return 2
    else:
        from ..sim.scenario import load
        from ..sim import simulate
        from ..sim.ublox import UbloxSimSource

        sc = load(args.scenario)
        source, what = UbloxSimSource(simulate(sc, args.seed), sensors=not args.bp3010), f"scenario {sc.name}"
    em = UbloxEmulators(Path(args.dir), source, speed=args.speed, gps_baud=args.baud, bp3010=args.bp3010,
                        config_fault=args.config_fault, serve_all=bool(args.ubx))
    imu = f" and a BP3010 on {Path(args.dir) / 'imu'}" if args.bp3010 else ""
    return serve_until_signalled(em, f"serving {what} ({source.duration_s:.0f} s at speed {args.speed:g}) as a u-blox "
                                     f"receiver on {Path(args.dir) / 'gps'} ({args.baud} Bd){imu}")
