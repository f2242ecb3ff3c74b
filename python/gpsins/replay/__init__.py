"""Replay: a logger session or a data set through the filter, into a results directory.

- ``run``: the replay itself; ``solution``: the solution on its way to disk; ``results``: the results
  directory written and read back; ``score``: solutions computed elsewhere scored the same way.
"""
