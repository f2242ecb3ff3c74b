"""Readers never raise on damaged input: the NumPy record reader and the streaming finder under random
mutations, and the stamp checks the checksum cannot make (spec/logfile.md)."""

import json
import re
import struct
import tempfile
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from corpora import (STAMP_T0, Corpus, FuzzTally, bp_frames, fuzz_finder_case, fuzz_reader_case, mutate, record_file,
                     ss2_frames)
from gpsins.session import dump, logs
from gpsins.session import stamps as stamps_mod
from gpsins.session import scan as log_scan
from gpsins.session import layouts
from gpsins.cli import main as cli_main
from gpsins.formats.common import ReaderError
from gpsins.formats import imu_csv, kfgins, rinex, rtklib_pos, rtklib_tag, ubx
from gpsins.formats.gpstime import UNIX_TO_GPS_S
from gpsins.formats.common import Fixes, Navigation
from gpsins_logger import superstar2 as ss2
from gpsins_logger.recorder import CLOCK_STEP_THRESHOLD_S

CORPORA = [Corpus("superstar2", ss2_frames(6.0), ss2.HEADER_LEN, 0.05), Corpus("bp3010", bp_frames(300), 1, 1 / 64)]
CASES = 300  # per corpus and per reader: 4 x 300 = 1200 mutated files per run


@pytest.mark.parametrize("case", [fuzz_reader_case, fuzz_finder_case], ids=["numpy-reader", "streaming-finder"])
@pytest.mark.parametrize("corpus", CORPORA, ids=lambda c: c.device)
def test_mutated_input_never_raises_and_keeps_intact_records(case, corpus):
    rng = np.random.default_rng([7, len(corpus.frames)])
    total = FuzzTally()
    for _ in range(CASES):
        total.add(case(corpus, rng))
    assert total.crashes == 0, total.first_crash
    assert total.intact > 50 * CASES
    # Additive checksums pass flips that cancel (+2^k in one byte, -2^k in another): rare, and the only way in.
    assert total.damaged_accepted <= 0.02 * CASES, total
    if case is fuzz_finder_case and corpus.device == "superstar2":
        assert total.intact_lost == 0, total
    else:
        # BP3010 hunting: an intact frame amid dense damage may go unconfirmed. Reader: a splice that copies a run
        # of whole records elsewhere leaves two runs of stamps out of order, and the neighbour test may pick the
        # wrong one. Both about 5e-5 of intact records in bench_fuzz.py.
        assert total.intact_lost <= 2e-4 * total.intact, total


@pytest.mark.parametrize("corpus", CORPORA, ids=lambda c: c.device)
def test_a_single_bit_flip_is_caught_or_harmless(corpus):
    """Every single-bit flip: the device checksum catches it, or it hit the stamp, which is then dropped or kept
    within a neighbour's gap plus a clock step of the truth. Nothing else is lost."""
    data = np.frombuffer(corpus.records_bytes, np.uint8)
    limits = stamps_mod.StampLimits(STAMP_T0 - 2, STAMP_T0 + len(corpus.frames) * corpus.dt + 2)
    rng = np.random.default_rng(3)
    for bit in rng.choice(8 * len(data), 400, replace=False):
        d = data.copy()
        d[bit // 8] ^= np.uint8(1 << (bit % 8))
        scanned = log_scan.scan(d.tobytes(), layouts.LAYOUTS[corpus.device], limits=limits)
        s = stamps_mod.reject_bad_stamps(scanned, limits)
        assert s.count >= len(corpus.recs) - 1
        for k in range(s.count):
            f = s.frame(k)
            assert f in corpus.frame_set
            err = min(abs(s.stamps[k] - x) for x in corpus.stamps_of[f])
            assert err <= corpus.dt + CLOCK_STEP_THRESHOLD_S


def _session(tmp_path, stamps):
    """A session directory with one IMU file holding the given stamps."""
    frames = bp_frames(len(stamps))
    d = tmp_path / "s"
    d.mkdir()
    data = b"".join(f[:1] + struct.pack("<d", t) + f[1:] for f, t in zip(frames, stamps))
    (d / "imu-000.bin").write_bytes(data)
    (d / "clock.csv").write_text(f"realtime,monotonic\n{STAMP_T0},100.0\n{STAMP_T0 + 5},105.0\n")
    (d / "session.json").write_text(json.dumps({
        "format": "gpsins-session", "start": {"realtime": STAMP_T0, "monotonic": 100.0},
        "stop": {"realtime": STAMP_T0 + 5, "monotonic": 105.0},
        "sensors": {"imu": {"device": "bp3010", "header_len": 1, "rate_hz": 64, "files": ["imu-000.bin"]}}}))
    return d, frames


@pytest.mark.parametrize("damage", ["exponent_bit", "sign_bit", "tiny", "nan", "one_second_ahead", "far_back"])
def test_an_impossible_stamp_is_dropped_counted_and_its_neighbours_kept(tmp_path, damage):
    stamps = STAMP_T0 + 0.5 + np.arange(200) / 64
    bad = {"exponent_bit": lambda t: struct.unpack("<d", (struct.unpack("<Q", struct.pack("<d", t))[0]
                                                         ^ (1 << 55)).to_bytes(8, "little"))[0],
           "sign_bit": lambda t: -t, "tiny": lambda t: 7e-300, "nan": lambda t: float("nan"),
           "one_second_ahead": lambda t: t + 1.0, "far_back": lambda t: t - 0.5}[damage]
    hit = [57, 58] if damage == "tiny" else [57]  # two stamps of 7e-300 crashed alignment before
    for k in hit:
        stamps[k] = bad(stamps[k])
    d, frames = _session(tmp_path, stamps)
    s = logs.read_session(d)
    imu = s.imu()
    keep = [k for k in range(200) if k not in hit]
    assert s.sensors["imu"].frames() == [frames[k] for k in keep]
    assert np.array_equal(imu.stamps, stamps[keep])
    st = s.sensors["imu"].stats()
    assert st["bad_stamps"] == len(hit) and st["stamps_backwards"] == 0
    assert s.sensors["imu"].scans[0].stats["first_bad_stamp_offset"] == hit[0] * 24
    summary = dump.session_summary(d)["sensors"]["imu"]
    assert summary["records"] == 198 if damage == "tiny" else 199
    assert summary["damage"][0]["first_bad_stamp_offset"] == hit[0] * 24


def test_a_clock_step_in_the_clock_pairs_is_not_damage(tmp_path):
    stamps = STAMP_T0 + 0.5 + np.arange(200) / 64
    stamps[100:] -= 0.8  # the system clock was stepped back 0.8 s (NTP at boot)
    d, frames = _session(tmp_path, stamps)
    (d / "clock.csv").write_text(f"realtime,monotonic\n{STAMP_T0},100.0\n{STAMP_T0 + 4.2},105.0\n")
    s = logs.read_session(d)
    assert s.sensors["imu"].count == 200 and s.sensors["imu"].stats()["bad_stamps"] == 0


def test_a_file_holding_only_a_truncated_record(tmp_path):
    # What a short write at the start of a part leaves.
    data, recs = record_file(bp_frames(3), 1, 1 / 64)
    for n in range(1, len(recs[0])):
        s = log_scan.scan(data[:n], layouts.BP_RECORDS)
        assert s.count == 0 and s.stats["truncated_tail_bytes"] + s.stats["discarded_bytes"] == n
    f = tmp_path / "gps-000.bin"
    f.write_bytes(bytes.fromhex("0117e8400000"))
    s = logs.read_record_file(f, "superstar2")
    assert s.count == 0 and s.stats["truncated_tail_bytes"] == 6


def test_dump_raw_on_a_truncated_superstar2_header(tmp_path, capsys):
    f = tmp_path / "cut.bin"
    f.write_bytes(bytes.fromhex("0117e8400000"))
    assert cli_main(["dump", "--raw", "superstar2", str(f), "--format", "json"]) == 0
    js = json.loads(capsys.readouterr().out)
    assert js["frames"] == 0 and js["truncated_tail_offset"] == 0 and js["truncated_tail_bytes"] == 6
    assert cli_main(["dump", "--raw", "bp3010", str(f), "--format", "json"]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == 0


def test_an_intact_record_after_a_false_incomplete_header_is_kept():
    # A false Superstar II header near the end claims more bytes than are left; whole records follow it.
    data, recs = record_file(ss2_frames(2.0), ss2.HEADER_LEN, 0.05)
    false = bytes([ss2.SOH, 7, 7 ^ 0xFF, 250])
    cut = len(data) - len(recs[-1]) - len(recs[-2])
    s = log_scan.scan(data[:cut] + false + data[cut:], layouts.SS2_RECORDS)
    assert s.count == len(recs) and s.stats["discarded_bytes"] == 4 and s.stats["truncated_tail_bytes"] == 0


# --- outside-format readers -----------------------------------------------------------------------------------
#
# Small slices of the files in tests/data (a few records each, so that thousands of cases take seconds), mutated
# as damaged files are: bits flipped, bytes inserted or deleted, the file cut, a digit changed, a field deleted,
# a number replaced by nan or inf; UBX frames also get a changed payload with a good checksum, tag files a
# changed word. Each case is one of: read (everything handed on finite and in time order), a ReaderError naming
# the file and the line, offset or field, or a failure (any other exception, an unlocated error, non-finite
# values or times out of order handed on).

DATA = Path(__file__).parent / "data"
WALK = DATA / "walk_0827"
WEEK = 2381
IMU_COLUMNS = ["t", "ax", "ay", "az", "gx", "gy", "gz"]
COUNTER_COLUMNS = ["ax", "ay", "az", "gx", "gy", "gz", "counter"]
NUMBER = re.compile(rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eEdD][-+]?\d+)?")
NON_FINITE = (b"nan", b"inf", b"-inf", b"NaN", b"1e999", b"-1D999", b"Infinity")
READ_OUTCOMES = ("read", "ReaderError")  # everything else is a failure


@dataclass
class ReaderCorpus:
    name: str
    file_name: str  # what the mutated file is called (the error must name it)
    data: bytes
    read: object  # Path -> result
    binary: bool = False  # binary layout: an offset locates an error as a line does in text


def _head_lines(path: Path, n: int, start: int = 0) -> bytes:
    return b"".join(path.read_bytes().splitlines(keepends=True)[start:start + n])


def _rinex_slice(path: Path, records: int) -> bytes:
    """The header and the first ``records`` navigation records (8 lines) or observation epochs."""
    lines = path.read_bytes().splitlines(keepends=True)
    end = next(k for k, x in enumerate(lines) if b"END OF HEADER" in x) + 1
    if b"NAV" in lines[0]:
        return b"".join(lines[:end + 8 * records])
    epoch = re.compile(rb"^ \d\d [ \d]\d [ \d]\d [ \d]\d [ \d]\d [ \d]\d\.\d{7}  \d")
    starts = [k for k in range(end, len(lines)) if epoch.match(lines[k])]
    return b"".join(lines[:starts[records]])


def _kfgins_imu_text(rows: int) -> bytes:
    """The walk's first IMU samples as KF-GINS increments (seconds of week, rad, m/s)."""
    a = np.loadtxt(WALK / "imu_1730_sf.csv", delimiter=",", usecols=range(7), max_rows=rows + 1)
    dt = np.diff(a[:, 0])[:, None]
    sow = a[1:, 0] - UNIX_TO_GPS_S - WEEK * 604800
    return "".join(f"{t:.6f} " + " ".join(f"{x:.9e}" for x in (*(g * d), *(f * 9.80665 * d))) + "\n"
                   for t, g, f, d in zip(sow, a[1:, 4:7], a[1:, 1:4], dt)).encode()


def _kfgins_gnss_text(rows: int) -> bytes:
    """The walk's first .pos fixes as a 13-column KF-GINS GNSS file (velocity north, east, down)."""
    text = [x for x in (WALK / "gnss_1730_sf.pos").read_text().splitlines() if not x.startswith("%")][:rows]
    out = []
    for line in text:
        tok = line.split()
        h, m, s = tok[1].split(":")
        sow = 4 * 86400 + int(h) * 3600 + int(m) * 60 + float(s)  # 2025-08-28 is a Thursday
        v = [float(x) for x in tok[2:]]
        out.append(f"{sow:.3f} {v[0]:.9f} {v[1]:.9f} {v[2]:.4f} {v[6]:.4f} {v[7]:.4f} {v[8]:.4f} "
                   f"{v[14]:.4f} {v[15]:.4f} {-v[16]:.4f} {v[17]:.4f} {v[18]:.4f} {v[19]:.4f}\n")
    return "".join(out).encode()


def _ubx_slice(epochs: int = 4) -> bytes:
    """Frames of the walk's capture, in their order: the first RXM-RAWX and NAV-PVT epochs and the RXM-SFRBX frames
    that make the first ephemeris of G10 (10 subframes) and of E07 (60 pages)."""
    data = (WALK / "gnss_1730.ubx").read_bytes()
    frames, _ = ubx.split_frames(data)
    wanted = {(0x02, 0x15): epochs, (0x01, 0x07): epochs, (0, 10): 10, (2, 7): 60}
    out = []
    for p, cls, mid, start, n in frames:
        key = (data[start], data[start + 1]) if (cls, mid) == (0x02, 0x13) else (cls, mid)
        if wanted.get(key, 0) > 0:
            wanted[key] -= 1
            out.append(data[p:p + 8 + n])
    return b"".join(out)


def reader_corpora() -> list[ReaderCorpus]:
    from test_readers import write_rinex3_nav, write_rinex3_obs  # noqa: PLC0415 (the RINEX 3 writers)

    nav2 = _rinex_slice(DATA / "07590920.05n", 4)
    obs2 = _rinex_slice(DATA / "07590920.05o", 3)
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        (d / "n.05n").write_bytes(nav2)
        (d / "o.05o").write_bytes(obs2)
        write_rinex3_nav(d / "n.rnx", rinex.read_nav(d / "n.05n"))
        write_rinex3_obs(d / "o.rnx", rinex.read_obs(d / "o.05o"))
        nav3, obs3 = (d / "n.rnx").read_bytes(), (d / "o.rnx").read_bytes()
    pos = (WALK / "gnss_1730_sf.pos").read_bytes()
    return [
        ReaderCorpus("rinex2-nav", "m.05n", nav2, rinex.read_nav),
        ReaderCorpus("rinex2-nav-igs", "m.10n", _rinex_slice(DATA / "brdc1820.10n", 4), rinex.read_nav),
        ReaderCorpus("rinex3-nav", "m.rnx", nav3, rinex.read_nav),
        ReaderCorpus("rinex2-obs", "m.05o", obs2, lambda p: _with_l1(rinex.read_obs(p))),
        ReaderCorpus("rinex3-obs", "m.obs", obs3, lambda p: _with_l1(rinex.read_obs(p))),
        ReaderCorpus("rtklib-pos", "m.pos", pos[:pos.index(b"\n") + 1] + _head_lines(WALK / "gnss_1730_sf.pos", 30, 1),
                     rtklib_pos.read),
        ReaderCorpus("imu-csv", "m.csv", _head_lines(WALK / "imu_1730_sf.csv", 60),
                     lambda p: imu_csv.read(p, IMU_COLUMNS, "gpst_unix", "g", "rad/s")),
        ReaderCorpus("imu-csv-utc", "m.csv", _head_lines(WALK / "imu_1730_sf.csv", 60, 100),
                     lambda p: imu_csv.read(p, IMU_COLUMNS, "utc_unix", "g", "rad/s")),
        ReaderCorpus("imu-counter", "m.csv", _head_lines(WALK / "imu_1730.csv", 60),
                     lambda p: imu_csv.read_counter_rows(p, COUNTER_COLUMNS, "g", "deg/s")),
        ReaderCorpus("kfgins-imu", "m.txt", _kfgins_imu_text(60), lambda p: kfgins.read_imu(p, WEEK)),
        ReaderCorpus("kfgins-gnss", "m.txt", _kfgins_gnss_text(30), lambda p: kfgins.read_gnss(p, WEEK)),
        ReaderCorpus("rtklib-tag", "m.csv.tag", (WALK / "imu_1730.csv.tag").read_bytes()[:76 + 8 * 60],
                     rtklib_tag.read, binary=True),
        ReaderCorpus("ubx", "m.ubx", _ubx_slice(), ubx.read, binary=True),
    ]


def _with_l1(obs):
    obs.gps_l1()
    obs.gps_l2()
    return obs


def _not_finite(a) -> bool:
    return a is not None and not np.isfinite(np.asarray(a, float)).all()


def _mixed_nan(a) -> bool:
    """NaN beside finite values in a column: a value the file wrote as nan (a column the file lacks is all NaN)."""
    if a is None or not len(a):
        return False
    a = np.asarray(a, float).reshape(len(a), -1)
    nan = np.isnan(a)
    return bool(np.isinf(a).any() or (nan.any(0) & ~nan.all(0)).any())


def handed_on_non_finite(out) -> str:
    """What a reader's result hands on that the filter cannot take: non-finite values, times out of order ("" if
    nothing)."""
    if isinstance(out, imu_csv.ImuData):
        bad = [n for n in ("t_abs", "dtheta_rad", "dv_mps") if _not_finite(getattr(out, n))]
    elif isinstance(out, imu_csv.CounterRows):
        bad = [n for n in ("acc", "gyr") if _not_finite(getattr(out, n))]
    elif isinstance(out, Fixes):
        bad = [n for n in ("t_abs", "r_ecef") if _not_finite(getattr(out, n))] + \
            [n for n in ("sigma_ned_m", "v_ned_mps", "sigma_v_ned_mps") if _mixed_nan(getattr(out, n))]
    elif isinstance(out, rinex.ObsFile):
        bad = ["epoch time"] * any(not np.isfinite(t) for t, _, _ in out.epochs) + \
            ["observation"] * any(np.isinf(v).any() for _, _, v in out.epochs)
    elif isinstance(out, Navigation):
        bad = ["Klobuchar"] * _not_finite(out.alpha + out.beta) + \
            [f"ephemeris {n}" for e in out.ephemerides for n in dir(e)
             if not n.startswith("_") and isinstance(getattr(e, n), float) and not np.isfinite(getattr(e, n))]
    elif isinstance(out, ubx.UbxFile):
        p = out.pseudoranges
        bad = [n for n, a in (("RAWX time", out.rawx_t_abs), ("pseudorange time", p.t_abs), ("pseudorange", p.pr_m),
                              ("fix time", out.fixes.t_abs), ("fix position", out.fixes.r_ecef)) if _not_finite(a)]
        bad += ["Doppler"] * bool(np.isinf(p.doppler_hz).any())
        bad += ["navigation"] * bool(handed_on_non_finite(out.navigation))
    elif isinstance(out, rtklib_tag.TimeTags):
        bad = ["start time"] * (not np.isfinite(out.start_t_abs))
    else:
        raise TypeError(f"no finiteness check for {type(out).__name__}")
    # Times in order too: the filter takes them so (IMU strictly increasing; fixes and epochs not going back).
    if isinstance(out, imu_csv.ImuData) and np.any(np.diff(out.t_abs) <= 0):
        bad.append("IMU times not increasing")
    if isinstance(out, Fixes) and np.any(np.diff(out.t_abs) < 0):
        bad.append("fix times going back")
    if isinstance(out, rinex.ObsFile) and np.any(np.diff([t for t, _, _ in out.epochs]) <= 0):
        bad.append("epoch times not increasing")
    if isinstance(out, ubx.UbxFile) and np.any(np.diff(out.pseudoranges.t_abs) < 0):
        bad.append("pseudorange times going back")
    return ", ".join(bad[:3])


def _number_spans(data: bytes) -> list[tuple[int, int]]:
    return [m.span() for m in NUMBER.finditer(data)]


def text_mutation(data: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    """One mutation of a text file that keeps it text: a digit changed, a field deleted, a number made non-finite,
    a line deleted or repeated."""
    kind = ("digit", "field", "non-finite", "line")[int(rng.integers(4))]
    if kind == "digit":
        at = [m.start() for m in re.finditer(rb"\d", data)]
        if at:
            p = at[int(rng.integers(len(at)))]
            return data[:p] + bytes([48 + int(rng.integers(10))]) + data[p + 1:], kind
    elif kind == "field":
        tokens = [m.span() for m in re.finditer(rb"[^\s,]+,?", data)]
        if tokens:
            a, b = tokens[int(rng.integers(len(tokens)))]
            return data[:a] + data[b:], kind
    elif kind == "non-finite":
        spans = _number_spans(data)
        if spans:
            a, b = spans[int(rng.integers(len(spans)))]
            word = NON_FINITE[int(rng.integers(len(NON_FINITE)))]
            if rng.random() < 0.5:  # keep the width: fixed-column formats (RINEX) stay aligned
                word = word.rjust(b - a)[:max(b - a, len(word))]
            return data[:a] + word + data[b:], kind
    lines = data.splitlines(keepends=True)
    if lines:
        k = int(rng.integers(len(lines)))
        lines[k:k + 1] = [] if rng.random() < 0.5 else [lines[k], lines[k]]
    return b"".join(lines), kind


def word_mutation(data: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    """A time-tag field overwritten: a 4-byte word with a random value, or an 8-byte one with a non-finite double."""
    if len(data) < 8:
        return data, "word"
    b = bytearray(data)
    if rng.random() < 0.7:
        p = 4 * int(rng.integers(len(b) // 4))
        b[p:p + 4] = int(rng.integers(0, 1 << 32)).to_bytes(4, "little")
    else:
        p = int(rng.integers(len(b) - 7))
        b[p:p + 8] = struct.pack("<d", (np.nan, np.inf, -np.inf, 1e300, -1.0)[int(rng.integers(5))])
    return bytes(b), "word"


def frame_mutation(data: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    """A UBX frame's payload changed (random bytes, or a non-finite double) and its checksum made good again: what
    only the decoders, not the framing, can catch."""
    frames, _ = ubx.split_frames(data)
    if not frames:
        return data, "frame"
    p, _, _, start, n = frames[int(rng.integers(len(frames)))]
    b = bytearray(data)
    if n >= 8 and rng.random() < 0.4:
        q = start + int(rng.integers(n - 7))
        b[q:q + 8] = struct.pack("<d", (np.nan, np.inf, -np.inf, 1e300)[int(rng.integers(4))])
    else:
        for _ in range(int(rng.integers(1, 4))):
            if n:
                b[start + int(rng.integers(n))] = int(rng.integers(256))
    body = np.frombuffer(bytes(b[p + 2:start + n]), np.uint8).astype(np.int64)
    ck_a = int(body.sum()) & 0xFF
    ck_b = int((np.arange(len(body), 0, -1) * body).sum()) & 0xFF
    b[start + n:start + n + 2] = bytes([ck_a, ck_b])
    return bytes(b), "frame"


def mutate_for(corpus: ReaderCorpus, rng: np.random.Generator) -> tuple[bytes, list[str]]:
    data, kinds = corpus.data, []
    special = (frame_mutation if corpus.name == "ubx" else word_mutation) if corpus.binary else text_mutation
    for _ in range(int(rng.integers(1, 4))):
        if rng.random() < 0.6:
            data, kind = special(data, rng)
            kinds.append(kind)
        else:
            data, _, applied = mutate(data, rng, 1)
            kinds += applied
    return data, kinds


def read_outcome(corpus: ReaderCorpus, path: Path) -> tuple[str, str]:
    """(outcome, detail): "read", "ReaderError", or a failure's name."""
    try:
        out = corpus.read(path)
    except ReaderError as e:
        msg = str(e)
        where = e.line is not None or e.field is not None or (corpus.binary and e.offset is not None)
        if path.name not in msg or "\n" in msg or not where:
            return "ReaderError without file and line or field", msg
        return "ReaderError", msg
    except ValueError as e:
        return "bare ValueError", f"{e}"
    except Exception as e:  # noqa: BLE001 (the point: any other exception is a failure)
        return type(e).__name__, f"{e}"
    bad = handed_on_non_finite(out)
    return ("bad values handed on", bad) if bad else ("read", "")


def fuzz_readers(corpora, cases_per_reader: int, workdir: Path, seed: int = 0, on_case=None) -> dict:
    """Outcome counts per reader, and the first example of each failure."""
    tally, examples = {}, {}
    for corpus in corpora:
        rng = np.random.default_rng([seed, len(corpus.data), len(corpus.name)])
        counts = tally.setdefault(corpus.name, Counter())
        path = workdir / corpus.file_name
        for _ in range(cases_per_reader):
            data, kinds = mutate_for(corpus, rng)
            path.write_bytes(data)
            outcome, detail = on_case(corpus, path) if on_case else read_outcome(corpus, path)
            counts[outcome] += 1
            if outcome not in READ_OUTCOMES:
                examples.setdefault((corpus.name, outcome), f"{'+'.join(kinds)}: {detail[:200]}")
    return {"counts": tally, "examples": examples}


READER_CASES = 250  # per reader: 13 x 250 = 3250 mutated files per run (benchmarks/bench_fuzz.py --readers: more)


@pytest.fixture(scope="module")
def outside_corpora():
    return reader_corpora()


def test_mutated_outside_files_are_read_or_refused_with_one_located_reader_error(outside_corpora, tmp_path):
    result = fuzz_readers(outside_corpora, READER_CASES, tmp_path, seed=5)
    counts = result["counts"]
    failures = {name: {k: v for k, v in c.items() if k not in READ_OUTCOMES} for name, c in counts.items()}
    assert not any(failures.values()), ({k: v for k, v in failures.items() if v}, result["examples"])
    for name, c in counts.items():
        assert c["read"] > 0, (name, c)  # the mutations leave files that still read...
        if name != "ubx":  # (UBX skips damaged frames: refused only when no frame is left)
            assert c["ReaderError"] > 0.05 * READER_CASES, (name, c)  # ...and ones that cannot be read


def _rows_of(corpus: ReaderCorpus) -> list[tuple[int, int]]:
    """Byte spans of the corpus's data rows: the units a non-finite value drops (RINEX: GPS records)."""
    data, spans, pos = corpus.data, [], 0
    lines = data.splitlines(keepends=True)
    if corpus.name.endswith("-nav"):
        k = next(i for i, x in enumerate(lines) if b"END OF HEADER" in x) + 1
        pos = sum(len(x) for x in lines[:k])
        while k < len(lines):
            n = 8 if lines[k][:1] in b" 0123456789G" else 4  # RINEX 3: GLONASS and SBAS records have 4 lines
            size = sum(len(x) for x in lines[k:k + n])
            if n == 8:
                spans.append((pos, pos + size))
            k, pos = k + n, pos + size
        return spans
    for k, line in enumerate(lines):
        if not line.startswith(b"%") and not (corpus.name == "imu-counter" and k == 0):  # (a logger's cut line)
            spans.append((pos, pos + len(line)))
        pos += len(line)
    return spans


def _summary(out) -> dict:
    if isinstance(out, Navigation):
        return {"eph": [(e.prn, e.toe_s, e.sqrt_a, e.af0, e.week) for e in out.ephemerides], "alpha": out.alpha}
    if isinstance(out, rinex.ObsFile):
        return {"epochs": [(t, p, v.tolist()) for t, p, v in out.epochs]}
    names = {imu_csv.ImuData: ("t_abs", "dtheta_rad", "dv_mps"), imu_csv.CounterRows: ("counter", "acc", "gyr"),
             Fixes: ("t_abs", "r_ecef", "sigma_ned_m", "q", "ns", "v_ned_mps", "sigma_v_ned_mps")}[type(out)]
    return {n: np.asarray(getattr(out, n)).tolist() for n in names}


NUMERIC_TEXT = ["rinex2-nav", "rinex3-nav", "rtklib-pos", "imu-csv", "imu-counter", "kfgins-imu", "kfgins-gnss"]


@pytest.mark.parametrize("name", NUMERIC_TEXT)
def test_rows_with_nan_or_inf_are_dropped_counted_and_the_rest_read_as_without_them(outside_corpora, tmp_path,
                                                                                    name):
    corpus = next(c for c in outside_corpora if c.name == name)
    rows = _rows_of(corpus)
    hit = [0, len(rows) // 2, len(rows) - 1]
    data, without = bytearray(corpus.data), bytearray(corpus.data)
    for k, word in zip(sorted(hit, reverse=True), (b"nan", b"inf", b"-inf")):
        a, b = rows[k]
        numbers = _number_spans(corpus.data[a:b])
        # A value the reader uses: mid-row in a .pos and a RINEX record (an orbit line), else after the first.
        x, y = numbers[(len(numbers) // 2 if name in ("rtklib-pos", "rinex2-nav", "rinex3-nav") else 1) + k % 3]
        data[a + x:a + y] = word.rjust(y - x) if name.endswith("-nav") else word
        del without[a:b]
    (tmp_path / corpus.file_name).write_bytes(bytes(data))
    got = corpus.read(tmp_path / corpus.file_name)
    (tmp_path / corpus.file_name).write_bytes(bytes(without))
    expected = corpus.read(tmp_path / corpus.file_name)
    assert _summary(got) == _summary(expected)
    non_finite = {k: v for k, v in got.skipped.items() if "nan or inf" in k or "non-finite" in k}
    assert sum(non_finite.values()) == 3, got.skipped
    assert not handed_on_non_finite(got)


@pytest.mark.parametrize("name", ["rinex2-obs", "rinex3-obs"])
def test_observations_written_as_nan_or_inf_are_missing_and_counted(outside_corpora, tmp_path, name):
    corpus = next(c for c in outside_corpora if c.name == name)
    (tmp_path / corpus.file_name).write_bytes(corpus.data)
    clean = rinex.read_obs(tmp_path / corpus.file_name)
    text = corpus.data.decode()
    end = text.index("END OF HEADER")
    k0 = text.index(f"{clean.epochs[1][2][0][1]:14.3f}", end)  # the second epoch's first satellite's second value
    width = 14
    for word in ("nan", "inf"):
        damaged = text[:k0] + word.rjust(width) + text[k0 + width:]
        (tmp_path / corpus.file_name).write_bytes(damaged.encode())
        got = rinex.read_obs(tmp_path / corpus.file_name)
        assert got.skipped == {rinex.NON_FINITE_OBSERVATIONS: 1}
        assert np.isnan(got.epochs[1][2][0][1]) and not handed_on_non_finite(got)
        expected = [v.copy() for _, _, v in clean.epochs]
        expected[1][0][1] = np.nan
        for (t, p, v), (t0, p0, _), e in zip(got.epochs, clean.epochs, expected):
            assert t == t0 and p == p0
            np.testing.assert_array_equal(v, e)
