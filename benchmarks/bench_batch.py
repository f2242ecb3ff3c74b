"""gpsins batch on 1 and 2 local workers: the same 10 simulated sessions (90 s drives, seeds 0-9), default
against report2005; prints each wall time and the speed-up.

    python benchmarks/bench_batch.py [N_SESSIONS]
"""

import sys
import tempfile
import time
from pathlib import Path

from gpsins import batch, sim
from gpsins.montecarlo.runner import open_client
from gpsins.sim.scenario import parse
from gpsins.sim.session import write_session

START = {"gps_week": 1590, "gps_tow_s": 419400.0, "lat_deg": 59.37, "lon_deg": 17.95, "height_m": 30.0,
         "heading_deg": 160.0}


def main(n: int = 10) -> None:
    root = Path(tempfile.mkdtemp(prefix="bench_batch_"))
    sc = parse({"name": "bench", "start": START,
                "segment": [{"label": "stand", "duration_s": 20, "speed_mps": 0},
                            {"label": "drive", "duration_s": 70, "speed_mps": 10, "turn_deg": 90}]})
    for seed in range(n):
        write_session(sim.simulate(sc, seed=seed), root / "sessions" / f"s{seed}")
    arms = (batch.Arm("default"), batch.Arm("report2005", "report2005"))
    wall = {}
    for workers in (1, 2):
        with open_client(None, workers) as client:
            client.submit(lambda: None).result()  # the workers up before the clock starts
            t0 = time.perf_counter()
            batch.run([root / "sessions"], arms, root / f"out{workers}", client=client)
            wall[workers] = time.perf_counter() - t0
        print(f"{workers} worker(s): {2 * n} replays in {wall[workers]:.1f} s")
    print(f"speed-up 2 workers / 1: {wall[1] / wall[2]:.2f}x")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 10)
