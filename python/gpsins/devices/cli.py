"""``gpsins emulate``: the pty emulators serving a scenario or a recorded session.
"""

from __future__ import annotations

import sys
from pathlib import Path

from gpsins_logger import bp3010

from ..sim import simulate
from ..sim.cli import scenario_from_args


def run_emulate(args) -> int:
    from .emulate import Emulators, serve_until_signalled

    if args.session:
        from .sources import SessionSource

        source = SessionSource(args.session)
        what = f"session {args.session}"
    else:
        sc = scenario_from_args(args, "emulate")
        if sc is None:
            return 2
        if not any(sc.imu.rate_hz % r == 0 for r in bp3010.RATES_HZ):
            print(f"gpsins emulate: a {sc.imu.rate_hz} Hz IMU cannot be served as a BP3010 (it must be a multiple "
                  f"of one of its rates {bp3010.RATES_HZ}); `gpsins sim` writes such sessions directly",
                  file=sys.stderr)
            return 2
        from ..sim.messages import SimSource

        source = SimSource(simulate(sc, args.seed))
        what = f"scenario {sc.name}"
    em = Emulators(Path(args.dir), source, speed=args.speed)
    return serve_until_signalled(em, f"serving {what} ({source.duration_s:.0f} s at speed {args.speed:g}) on "
                                     f"{Path(args.dir) / 'gps'} and {Path(args.dir) / 'imu'}; the IMU starts when "
                                     "the host sends its rate command")
