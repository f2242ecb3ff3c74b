"""Replay: a logger session or a data set through the filter, into a results directory.

- ``run``: the replay itself (``replay``, ``run_mode``), over ``inputs`` (a session or data set decoded
  once for every mode); one mode's run is ``plan`` -> ``forward`` (forward pass, smoother) -> ``write``,
  with ``scoring`` (against a reference, through outages) and ``summary`` (the arrays, run.json's health);
- ``solution``: the solution on its way to disk; ``results``: the results directory written and read back;
- ``score``: solutions computed elsewhere scored the same way.
"""
