"""The navigation filter from Python.

- ``config``: the configuration language (presets in ``presets/``, TOML tables, ``--set``), its checks and
  the conversion to the core's ``InsConfig``;
- ``inputs``: the filter's inputs by columns; ``runs``: batch, chunked and streaming runs of the C++ core,
  the solution type, the heading search of a hand-held device;
- ``noise_from_data``, ``fix_scatter``, ``mounting``: what the recording itself says about the noise, the
  GNSS errors and the mounting;
- ``estimator``: anyone's estimator in the built-in filter's place.
"""
