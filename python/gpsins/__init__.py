"""gpsins: an experimental platform for validating GPS/INS integration algorithms.

Data flows one way: serial bytes -> frames -> records on disk -> decoded
measurements -> time-aligned streams -> filter -> solution -> report.
The C++ core (Earth model, attitude, filters) is ``gpsins._core``.
"""

__version__ = "0.1.0"
