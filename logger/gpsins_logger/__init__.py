"""gpsins vehicle logger: device protocols and the logging daemon.

Pure Python with pyserial as its only dependency, so it installs on a
minimal vehicle computer with ``pip install ./logger``.
"""

__version__ = "0.1.0"
