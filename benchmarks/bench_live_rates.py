"""gpsins live's follower at IMU rates the BP3010 emulator cannot serve (issue 39's 100 Hz IMU with 10 Hz
GNSS): a simulated session is grown again record by record as the logger wrote it (tests/growing.py), a
look every INTERVAL_S of the drive, and the follower's CPU time (its polls and clock fits, threads
included) is divided by the drive's length: the share of one core live would take at real time. The
growing copy's own file writes are timed alone and taken off. Prints figures; asserts nothing.

    python benchmarks/bench_live_rates.py [DRIVE_S] [INTERVAL_S]
"""

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from growing import GrowingCopy  # noqa: E402
from drives import START  # noqa: E402

from gpsins.live.follower import Follower  # noqa: E402
from gpsins.sim.scenario import parse  # noqa: E402
from gpsins.sim.session import simulate_session  # noqa: E402


def follow(src: Path, dst: Path, interval_s: float, with_follower: bool) -> tuple[float, int]:
    """CPU seconds of growing ``src`` into ``dst`` look by look (and following it); epochs out."""
    grown = GrowingCopy(src, dst)
    fol = Follower(dst) if with_follower else None
    epochs = 0
    lo, hi = grown.span
    c0 = time.process_time()
    for t in np.arange(lo, hi + interval_s, interval_s):
        grown.grow_to(t)
        if fol is not None:
            sol = fol.poll()
            epochs += 0 if sol is None else len(sol.t)
            if fol.fed:
                fol.maintain()
    grown.finish()
    while fol is not None and (sol := fol.poll(final=True)) is not None:
        epochs += len(sol.t)
    return time.process_time() - c0, epochs


def main(drive_s: float = 300.0, interval_s: float = 0.02) -> None:
    root = Path(tempfile.mkdtemp(prefix="bench_live_rates_"))
    print(f"drive {drive_s:.0f} s (60 s standing), a look every {interval_s} s of the drive")
    print("| IMU | fixes | CPU share of one core | epochs out |")
    print("| --- | --- | --- | --- |")
    for imu_hz, fix_hz in ((64, 1), (64, 10), (100, 10), (200, 10)):
        name = f"imu{imu_hz}_fix{fix_hz}"
        sc = parse({"name": name, "start": START, "imu": {"rate_hz": imu_hz}, "gnss": {"fix_rate_hz": fix_hz},
                    "timing": {"imu_baud": 115200},
                    "segment": [{"label": "stand", "duration_s": 60, "speed_mps": 0},
                                {"label": "drive", "duration_s": drive_s - 60, "speed_mps": 10, "turn_deg": 270}]})
        src = simulate_session(sc, 1, root / name / "recorded")
        grow_s, _ = follow(src, root / name / "grown_alone", interval_s, False)
        total_s, epochs = follow(src, root / name / "followed", interval_s, True)
        print(f"| {imu_hz} Hz | {fix_hz} Hz | {100 * (total_s - grow_s) / drive_s:.1f} % | {epochs} |")


if __name__ == "__main__":
    main(*(float(a) for a in sys.argv[1:3]))
