"""The logger's session files, read on the workstation: the stage between records on disk and the
measurements the filter takes.

- ``logs``: record layouts, the vectorised scanner, block-wise reading of growing files, stamp plausibility,
  whole sessions and raw device captures;
- ``measurements``: decoded Superstar II / BP3010 measurements and IMU increments; ``measurements_ubx`` the
  same for a u-blox receiver;
- ``growing``: a session as the logger writes it, read and decoded incrementally (for ``gpsins live``);
- ``dump``: what a session holds (``gpsins dump``).
"""
