"""What a device emulator serves: timed device messages and IMU samples, and the face of a
source of them (``MessageSource``). Shared by the simulator (``sim.messages``, ``sim.ublox``) and
the emulators' own sources (``devices.sources``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, Protocol


from gpsins_logger import bp3010


@dataclass(frozen=True)
class TimedMessage:
    t: float  # seconds since the start of the run
    msg_id: int
    frame: bytes
    tow_s: float | None = None  # GPS time of week of ID 23 measurements (for rate decimation)


@dataclass(frozen=True)
class TimedSample:
    t: float  # sampling instant (end of the increment's interval)
    sample: bp3010.ImuSample


class MessageSource(Protocol):
    duration_s: float

    def gps_messages(self) -> Iterator[TimedMessage]: ...
    def imu_samples(self, rate_hz: int, t0: float = 0.0) -> Iterator[TimedSample]: ...
