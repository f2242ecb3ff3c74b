"""Monte Carlo runs and parameter sweeps on Dask: simulate + replay per seed as Dask tasks.

    gpsins montecarlo SCENARIO --seeds N [--mode loose|tight|both] [--config ...] [--set k=v] [--outages SPEC]
                      [--sweep KEY=v1,v2,...] [--out DIR] [--scheduler ADDRESS | --workers K]
    gpsins sweep SCENARIO --key KEY --values v1,v2,... --seeds N [...]

``runner`` builds the task graph (``tasks``: one simulation per seed, one replay per seed, mode
and swept value, each in its own directory under ``--out``) on a local cluster of worker
processes or an existing scheduler; ``aggregate`` holds the statistics across runs (NEES and
NIS against their chi-square bands, errors per epoch, segment and outage); ``figure`` draws them.

Files in ``--out``: ``runs.csv`` (one row per run: seed, mode, swept value, status, the run's
errors, NEES, NIS per update kind, counters, wall times), ``segments.csv`` and ``outages.csv``
(one row per run and segment or outage), ``aggregate.json`` (per mode and value: the aggregate
NEES and NIS against their bands, error statistics, per segment and per outage, and the series
behind the figures), ``montecarlo_<mode>[_<value index>].png``, and ``seed-NNNN/`` with each
seed's session and replay results. Tables are CSV: a few hundred rows of scalars, read by
anything without pyarrow.
"""

from .runner import Outcome, Plan, open_client, run_plan

__all__ = ["Plan", "Outcome", "open_client", "run_plan"]
