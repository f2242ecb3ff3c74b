"""Outage drift on the real walk over shifted outage schedules (issues 16, 18).

    python benchmarks/bench_walk.py                        # both data sets, seven schedules
    python benchmarks/bench_walk.py --sets walk_0827 --shifts -10,0,10
    python benchmarks/bench_walk.py --set zero_rate_sigma_rad_per_s=1e-3   # a configuration variant

The issue's schedule (25:15:45:45) puts two 15 s outages into a 134 s walk: two numbers, whose
RMS moves by a metre when the outages start a few seconds earlier or later. This replays the
walk (RTKLIB .pos and the receiver's own NAV-PVT) with the same schedule shifted, and prints per
schedule and pooled (RMS over all outages of every schedule) the forward and smoothed RMS of the
per-outage maximum horizontal drift and the RMS error outside the outages.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from gpsins.nav import config as nav_config
from gpsins.replay import run

WALK = Path(__file__).resolve().parents[1] / "tests" / "data" / "walk_0827"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default="walk_0827,walk_0827_ubx")
    ap.add_argument("--shifts", default="-10,-6,-2,0,2,6,10", help="seconds added to the first outage's 25 s")
    ap.add_argument("--set", action="append", metavar="KEY=VALUE", help="override one configuration key")
    args = ap.parse_args()
    overrides = nav_config.parse_overrides(args.set or [])
    shifts = [float(x) for x in args.shifts.split(",")]
    for name in args.sets.split(","):
        fwd, smo, outside = [], [], []
        t0 = time.perf_counter()
        for shift in shifts:
            with tempfile.TemporaryDirectory() as d:
                res = run.replay(WALK / f"{name}.toml", Path(d) / "r", outages=f"{25 + shift:g}:15:45:45",
                                 smooth=True, overrides=overrides).summary
            f, s = res["scoring"], res["smoothed"]["scoring"]
            fwd += [o["max_h_m"] for o in f["per_outage"] if np.isfinite(o["max_h_m"])]
            smo += [o["max_h_m"] for o in s["per_outage"] if np.isfinite(o["max_h_m"])]
            outside.append(f["outside"]["rms_h_m"])
            print(f"{name} first outage at {25 + shift:4.0f} s: forward {f['horizontal_m']['rms']:.2f} m, smoothed "
                  f"{s['horizontal_m']['rms']:.3f} m, outside {f['outside']['rms_h_m']:.3f} m", flush=True)
        rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
        print(f"{name} pooled over {len(fwd)} outages: forward {rms(fwd):.2f} m (worst {max(fwd):.2f}), smoothed "
              f"{rms(smo):.3f} m (worst {max(smo):.3f}), outside {rms(outside):.3f} m; "
              f"{time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
