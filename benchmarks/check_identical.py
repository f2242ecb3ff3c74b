"""Bit-identical replays: the check for a change that must not change behaviour (a restructuring,
a build option). Make a reference with the code before the change, then compare after it:

    python benchmarks/check_identical.py run OUT              # the fixed set of replays into OUT
    python benchmarks/check_identical.py compare REF OUT      # exit 1 unless identical
    python benchmarks/check_identical.py check REF OUT        # run, then compare

The fixed set (about a minute or two on one core):

- the default simulated drive (``gpsins sim``, seed 0) replayed ``--mode both --smooth``
  (loose and tight, each forward and smoothed), and ``--mode ins``;
- the walk data set loose (``walk_0827.toml``, RTKLIB fixes, with its scored outages);
- the same walk tight from the u-blox receiver's own stream (``walk_0827_ubx.toml``).

Compared: ``solution.pos`` and ``smoothed.pos`` byte for byte, and every array a results
directory holds (``results.load``: ``results.npz``, the solution, smoothed and update tables)
exactly (NaN equal to NaN, same dtype and shape). ``run.json`` is not compared: it holds
timings; its counters are compared.
"""

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
WALK = ROOT / "tests" / "data" / "walk_0827"

# name -> gpsins command-line arguments after the source (the source is the simulated session
# for names starting "drive", else the data set given)
REPLAYS = {
    "drive": ("session", ["--mode", "both", "--smooth"]),
    "drive_ins": ("session", ["--mode", "ins"]),
    "walk_loose": (WALK / "walk_0827.toml", ["--mode", "loose"]),
    "walk_ubx_tight": (WALK / "walk_0827_ubx.toml", ["--mode", "tight"]),
}
TEXT_FILES = ("solution.pos", "smoothed.pos")


def gpsins(*args: str) -> None:
    cmd = [sys.executable, "-c", "import sys; from gpsins.cli import main; sys.exit(main(sys.argv[1:]))", *args]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)


def run(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    session = out / "session"
    if not session.exists():
        t0 = time.perf_counter()
        gpsins("sim", "--out", str(session), "--seed", "0")
        print(f"sim: {time.perf_counter() - t0:.1f} s")
    for name, (source, args) in REPLAYS.items():
        src = session if source == "session" else source
        t0 = time.perf_counter()
        gpsins("replay", str(src), "--out", str(out / name), *args)
        print(f"{name}: {time.perf_counter() - t0:.1f} s")


def result_dirs(root: Path) -> list[Path]:
    """Every results directory (one holding run.json) under root, relative to it; the session is not one."""
    return sorted(p.parent.relative_to(root) for p in root.rglob("run.json") if "session" not in p.parts)


def same_array(a: np.ndarray, b: np.ndarray) -> bool:
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    if a.dtype.kind in "fc":
        return bool(np.array_equal(a, b, equal_nan=True))
    return bool(np.array_equal(a, b))


def compare(ref: Path, out: Path) -> int:
    from gpsins.replay import results

    dirs = result_dirs(ref)
    if not dirs:
        print(f"{ref}: no results directories")
        return 1
    bad = 0
    for d in dirs:
        a, b = ref / d, out / d
        if not (b / "run.json").is_file():
            print(f"{d}: missing")
            bad += 1
            continue
        diffs = []
        for f in TEXT_FILES:
            if (a / f).exists() != (b / f).exists():
                diffs.append(f"{f} present in one only")
            elif (a / f).exists() and (a / f).read_bytes() != (b / f).read_bytes():
                diffs.append(f"{f} differs")
        ra, rb = results.load(a), results.load(b)
        if set(ra) != set(rb):
            diffs.append(f"arrays differ in name: {sorted(set(ra) ^ set(rb))}")
        unequal = [k for k in sorted(set(ra) & set(rb)) if not same_array(np.asarray(ra[k]), np.asarray(rb[k]))]
        if unequal:
            diffs.append(f"{len(unequal)} arrays differ: {', '.join(unequal[:12])}")
        ca = json.loads((a / "run.json").read_text()).get("counters")
        cb = json.loads((b / "run.json").read_text()).get("counters")
        if ca != cb:
            diffs.append("run.json counters differ")
        lines = sum(1 for _ in (a / "solution.pos").open()) if (a / "solution.pos").exists() else 0
        print(f"{str(d) or '.'}: {len(ra)} arrays, {lines} .pos lines: " + ("; ".join(diffs) if diffs else "identical"))
        bad += bool(diffs)
    print(f"{len(dirs) - bad} of {len(dirs)} results directories identical")
    return 1 if bad else 0


def main(argv: list[str]) -> int:
    if len(argv) >= 2 and argv[0] == "run":
        run(Path(argv[1]))
        return 0
    if len(argv) >= 3 and argv[0] == "compare":
        return compare(Path(argv[1]), Path(argv[2]))
    if len(argv) >= 3 and argv[0] == "check":
        run(Path(argv[2]))
        return compare(Path(argv[1]), Path(argv[2]))
    print(__doc__)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
