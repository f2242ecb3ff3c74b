"""gpsins batch on 1 and 2 local workers: the same 20 simulated sessions (the default 287 s drive, seeds
0-19), default against report2005; prints each wall time and the speed-up (short drives measure Dask's
overheads, not the replays).

    python benchmarks/bench_batch.py [N_SESSIONS]
"""

import sys
import tempfile
import time
from pathlib import Path

from gpsins.montecarlo import batch
from gpsins import sim
from gpsins.sim import scenario
from gpsins.montecarlo.runner import open_client
from gpsins.sim.session import write_session


def main(n: int = 20) -> None:
    root = Path(tempfile.mkdtemp(prefix="bench_batch_"))
    sc = scenario.load("default")
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
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 20)
