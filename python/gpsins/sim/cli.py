"""``gpsins sim`` and ``gpsins emulate``."""

from __future__ import annotations

import signal
import sys
import time
from pathlib import Path

from . import load, simulate
from .scenario import ScenarioError


def run_sim(args) -> int:
    try:
        sc = load(args.scenario)
    except ScenarioError as e:
        print(f"gpsins sim: {e}", file=sys.stderr)
        return 2
    out = Path(args.out)
    if out.exists():
        print(f"gpsins sim: {out} exists; give a new directory", file=sys.stderr)
        return 2
    from .session import write_session

    t = time.perf_counter()
    sim = simulate(sc, args.seed)
    write_session(sim, out)
    print(f"simulated {sc.name} ({sc.duration_s:.0f} s, seed {args.seed}) in {time.perf_counter() - t:.1f} s: {out}")
    if getattr(args, "dataset", False):
        from .dataset_writer import write_dataset

        print(f"data set (known mounting, lever arm, IMU time offset): {write_dataset(sim, out / 'dataset')}")
    return 0


def run_emulate(args) -> int:
    from ..emulate import Emulators

    if args.session:
        from ..sources import SessionSource

        source = SessionSource(args.session)
        what = f"session {args.session}"
    else:
        try:
            sc = load(args.scenario)
        except ScenarioError as e:
            print(f"gpsins emulate: {e}", file=sys.stderr)
            return 2
        from .messages import SimSource

        source = SimSource(simulate(sc, args.seed))
        what = f"scenario {sc.name}"
    em = Emulators(Path(args.dir), source, speed=args.speed)
    stop = {"now": False}
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.update(now=True))
    em.start()
    print(f"serving {what} ({source.duration_s:.0f} s at speed {args.speed:g}) on {Path(args.dir) / 'gps'} and "
          f"{Path(args.dir) / 'imu'}; the IMU starts when the host sends its rate command", flush=True)
    try:
        while not stop["now"] and not em.wait(0.2):
            pass
    finally:
        em.stop()
    return 0
