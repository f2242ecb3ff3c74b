"""Replay speed and memory, whole process, per scenario.

    python benchmarks/bench_replay.py                      # the default drive
    python benchmarks/bench_replay.py default long         # and the 43-minute drive
    python benchmarks/bench_replay.py long --session DIR   # an existing session (e.g. a 24-hour one)

For each scenario a session is simulated (``gpsins sim``, its own process), then, from a
fresh runner process, ``gpsins replay SESSION --mode both`` runs as a child and is timed from the
outside: wall time of the whole process (interpreter start, imports, decoding,
alignment, both filters, writing) and its peak RSS. Prints one line per case and, with
--json, the figures. Targets: the default drive <= 1.0 s whole process; the
43-minute drive <= 0.3 GB; a 24-hour drive <= 1 GB.
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _child(cmd: list[str]) -> tuple[float, float]:
    """Wall time (s) and peak RSS (MB) of one command run as a child process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    # ru_maxrss of the children is the largest of any child so far: run each case in a fresh runner.
    return wall, max(peak, before) / 1024.0


def simulate(scenario: str, directory: str) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "gpsins.cli", "sim", "--scenario", scenario, "--out", directory], check=True,
                   stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def case(scenario: str, session: str, mode: str, repeats: int, extra: list[str]) -> dict:
    """The replays of one session, run from a fresh runner process whose only children they are."""
    gpsins = [sys.executable, "-m", "gpsins.cli"]
    with tempfile.TemporaryDirectory() as tmp:
        size_mb = sum(p.stat().st_size for p in Path(session).glob("*.bin")) / 1e6
        walls, peak = [], 0.0
        for _ in range(repeats):
            w, peak = _child(gpsins + ["replay", session, "--mode", mode, "--out", os.path.join(tmp, "out")] + extra)
            walls.append(w)
        run = json.loads(Path(tmp, "out", "loose" if mode == "both" else "", "run.json").read_text())
        logged_h = run["imu_samples"] / run.get("dataset", {}).get("imu_rate_hz", 64.0) / 3600.0
    return {"scenario": scenario, "mode": mode, "log_mb": round(size_mb, 1),
            "replay_wall_s_best": round(min(walls), 3), "replay_wall_s": [round(w, 3) for w in walls],
            "replay_peak_rss_mb": round(peak, 1), "logged_hours": round(logged_h, 3),
            "wall_s_per_logged_hour": round(min(walls) / logged_h, 2) if logged_h else None,
            "filter_s_loose": round(run["wall_time_s"]["filter_s"], 3)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenarios", nargs="*", default=["default"])
    ap.add_argument("--session", help="replay this session instead of simulating (one scenario name as its label)")
    ap.add_argument("--mode", default="both")
    ap.add_argument("--repeats", type=int, default=3, help="replays per case (the best wall time counts)")
    ap.add_argument("--json", help="also write the figures here")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--replay-arg", action="append", default=[], help="an extra replay argument (repeatable)")
    args = ap.parse_args()
    extra = args.replay_arg
    if args.child:
        print(json.dumps(case(args.scenarios[0], args.session, args.mode, args.repeats, extra)))
        return
    rows = []
    for sc in args.scenarios:  # one runner process per case, so that each peak is its own
        with tempfile.TemporaryDirectory() as tmp:
            session, sim_s = args.session, float("nan")
            if session is None:
                session = os.path.join(tmp, "session")
                sim_s = simulate(sc, session)
            cmd = [sys.executable, __file__, sc, "--child", "--mode", args.mode, "--repeats", str(args.repeats),
                   "--session", session]
            out = subprocess.run(cmd + [f"--replay-arg={a}" for a in extra], check=True, capture_output=True,
                                 text=True)
        row = json.loads(out.stdout.strip().splitlines()[-1])
        row["sim_s"] = round(sim_s, 2)
        rows.append(row)
        print(f"{row['scenario']:10s} {row['log_mb']:8.1f} MB log  replay --mode {row['mode']}: "
              f"{row['replay_wall_s_best']:.3f} s best of {row['replay_wall_s']}, "
              f"peak {row['replay_peak_rss_mb']:.0f} MB,"
              f" {row['wall_s_per_logged_hour']} s per logged hour (sim {row['sim_s']} s)", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
