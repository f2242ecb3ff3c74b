"""Fuzz the readers: mutated record files (NumPy reader) and raw streams (streaming finder); with --readers the
outside-format readers (RINEX, .pos, IMU CSV, KF-GINS, time tags, UBX) on mutated slices of tests/data.

    python benchmarks/bench_fuzz.py [MUTATED_FILES]
    python benchmarks/bench_fuzz.py --readers [MUTATED_FILES]

Default 100000, split evenly over {reader, finder} x {Superstar II, BP3010}.
Each case applies 1-3 mutations (bit flips, insertions, deletions, a
truncation, splices). Prints per reader and device: crashes, hangs (a case
over 2 s), intact records lost, damaged records accepted (device bytes that
are no sent frame: flips that cancel in an additive checksum), and records
kept with a changed stamp (the stamp is outside the checksum) with the worst
error over (neighbour gap + clock step).

--readers: default 13500 mutated files, split evenly over the readers; prints per reader how many were read,
refused with a ReaderError naming file and line/offset/field, and every failure by kind (another exception
type, a bare ValueError, an error without a location, non-finite values handed on, a hang over 2 s) with its
first example.
"""

import signal
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from corpora import Corpus, FuzzTally, bp_frames, fuzz_finder_case, fuzz_reader_case, ss2_frames  # noqa: E402

from gpsins_logger import superstar2 as ss2  # noqa: E402

HANG_S = 2.0


class Hang(Exception):
    pass


def _alarm(*_):
    raise Hang()


def outside_readers(total: int) -> None:
    import tempfile

    import test_fuzz as tf

    corpora = tf.reader_corpora()
    per = total // len(corpora)
    signal.signal(signal.SIGALRM, _alarm)

    def timed(corpus, path):
        signal.setitimer(signal.ITIMER_REAL, HANG_S)
        try:
            return tf.read_outcome(corpus, path)
        except Hang:
            return "hang", ""
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)

    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        result = tf.fuzz_readers(corpora, per, Path(d), seed=11, on_case=timed)
    wall = time.perf_counter() - start
    print(f"{per * len(corpora)} mutated files ({per} per reader); {wall:.0f} s")
    total_counts = {}
    for name, counts in result["counts"].items():
        for k, v in counts.items():
            total_counts[k] = total_counts.get(k, 0) + v
        print(f"  {name:15s} " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items(), key=lambda x: -x[1])))
    print("  all             " + ", ".join(f"{k} {v}" for k, v in sorted(total_counts.items(), key=lambda x: -x[1])))
    for (name, outcome), example in result["examples"].items():
        print(f"    {name} {outcome}: {example}")


def main() -> None:
    if sys.argv[1:2] == ["--readers"]:
        outside_readers(int(sys.argv[2]) if len(sys.argv) > 2 else 13_500)
        return
    total = int(sys.argv[1]) if len(sys.argv) > 1 else 100_000
    corpora = [Corpus("superstar2", ss2_frames(6.0), ss2.HEADER_LEN, 0.05), Corpus("bp3010", bp_frames(300), 1, 1 / 64)]
    signal.signal(signal.SIGALRM, _alarm)
    per = total // 4
    print(f"{4 * per} mutated inputs ({per} per reader and device)")
    for name, case in (("numpy reader", fuzz_reader_case), ("streaming finder", fuzz_finder_case)):
        for c in corpora:
            rng = np.random.default_rng([11, len(c.frames), len(name)])
            t, hangs, start = FuzzTally(), 0, time.perf_counter()
            for _ in range(per):
                signal.setitimer(signal.ITIMER_REAL, HANG_S)
                try:
                    t.add(case(c, rng))
                except Hang:
                    hangs += 1
                finally:
                    signal.setitimer(signal.ITIMER_REAL, 0)
            wall = time.perf_counter() - start
            print(f"  {name:16s} {c.device:10s}: crashes {t.crashes}, hangs {hangs}, intact records lost "
                  f"{t.intact_lost} of {t.intact}, damaged records accepted {t.damaged_accepted}, "
                  f"kept with a changed stamp {t.stamp_changed_accepted} (worst error / (gap + step) "
                  f"{t.worst_stamp_error_over_gap:.3f}); {wall:.0f} s")
            if t.first_crash:
                print(f"    first crash: {t.first_crash}")


if __name__ == "__main__":
    main()
