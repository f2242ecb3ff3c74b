"""``gpsins sim``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path


from . import DEFAULT_BLOCK_S
from .scenario import load
from .scenario import ScenarioError, with_imu_rate


def scenario_from_args(args, command: str):
    """The scenario of the command line, at --imu-rate when given; None after printing the error."""
    try:
        sc = load(args.scenario)
        if getattr(args, "imu_rate", None):
            sc = with_imu_rate(sc, args.imu_rate)
        return sc
    except ScenarioError as e:
        print(f"gpsins {command}: {e}", file=sys.stderr)
        return None


def run_sim(args) -> int:
    sc = scenario_from_args(args, "sim")
    if sc is None:
        return 2
    out = Path(args.out)
    if out.exists():
        print(f"gpsins sim: {out} exists; give a new directory", file=sys.stderr)
        return 2
    fix_rate_hz = getattr(args, "fix_rate", 5.0)
    if not fix_rate_hz > 0:
        print(f"gpsins sim: --fix-rate must be > 0 Hz, got {fix_rate_hz:g}", file=sys.stderr)
        return 2
    block_s = getattr(args, "block_s", None)
    if block_s is not None and not block_s > 0:
        print(f"gpsins sim: --block-s must be > 0 s, got {block_s:g}", file=sys.stderr)
        return 2
    t = time.perf_counter()
    from .session import simulate_session

    dataset = out / "dataset" if getattr(args, "dataset", False) else None
    simulate_session(sc, args.seed, out, block_s or DEFAULT_BLOCK_S, dataset, fix_rate_hz)
    print(f"simulated {sc.name} ({sc.duration_s:.0f} s, IMU at {sc.imu.rate_hz} Hz, seed {args.seed}) in "
          f"{time.perf_counter() - t:.1f} s: {out}")
    if dataset is not None:
        print(f"data set (known mounting, lever arm, IMU time offset): {dataset / 'dataset.toml'}")
    return 0
