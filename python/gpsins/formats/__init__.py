"""File and message formats: readers of outside formats, one module per format, all giving the
containers of ``common``, and the formats the simulator shares with the workstation.

- ``imu_csv``: IMU CSV with declared columns, units and time scale (rates or increments)
- ``kfgins``: KF-GINS IMU and GNSS text files
- ``rtklib_pos``: RTKLIB ``.pos`` solutions (Q, standard deviations, velocities)
- ``rinex``: RINEX 2 and 3 observation and GPS navigation files
- ``ubx``: u-blox UBX (RXM-RAWX, RXM-SFRBX GPS LNAV, NAV-PVT)
- ``rtklib_tag``: RTKLIB time-tag files (a logged stream's arrival times)
- ``solution_csv``: a navigation solution as a text table with declared columns
- ``galileo_inav``: Galileo I/NAV pages to broadcast ephemerides
- ``gpstime``: GPS time (epoch, weeks, leap seconds)
- ``truth``: a simulated session's ``truth.npz``; ``reference``: the reference system's ``reference.csv``
- ``messages``: the timed device messages an emulator serves; ``nmea``: NMEA 0183 sentences of a solution

Files whose names end in .gz are read through gzip. Damaged input raises ``ReaderError`` naming the file,
the offset or line and the field; binary streams skip damaged frames and count them instead.
"""

from .common import Fixes, Navigation, Pseudoranges, ReaderError  # noqa: F401
