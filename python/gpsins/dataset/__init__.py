"""Data sets: recordings that are not logger sessions, described by a TOML file.

- ``load``: the data-set file, read and checked, and its recordings read into the filter's inputs;
- ``init``: a first data-set TOML for someone's own recording (``gpsins dataset init``);
- ``doctor``: the data-set doctor, the data checked against what the TOML declares (``gpsins check``).
"""
