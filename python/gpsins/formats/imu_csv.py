"""IMU text tables (CSV or whitespace) with declared columns, units and time scale.

Rates (g, m/s^2, rad/s, deg/s) become increments over each sampling interval by the
trapezoid rule, so n rate samples give n - 1 increments ending at samples 1..n-1, and
together they cover every step, a long one too;
increments (m/s, rad, deg) are taken as they are, each ending at its own time stamp.
Samples whose time does not increase, and rows with a value written as nan or inf, are
dropped and counted (``skipped``); a value that is not a number is an error naming the file,
line and column.

A stream logged raw has no time column but the sensor's own sample counter:
``read_counter_rows`` gives its rows with where each line ends, for the logger's arrival
times (``rtklib_tag``) and the alignment (``timing.envelope.counter_times``); ``from_samples``
then makes the increments.
"""

from __future__ import annotations

import datetime as dt
import gzip
import re
import warnings
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .common import NON_FINITE_ROWS, ReaderError, finite_rows, read_bytes, read_head
from .gpstime import SECONDS_PER_WEEK, UNIX_TO_GPS_S, leap_seconds

HEAD_BYTES = 1 << 20  # where the header and the delimiter are looked for (the first 1000 lines at most)

G0 = 9.80665  # standard gravity: what "g" means in IMU data sheets
ACCEL_UNITS = {"g": (G0, True), "m/s^2": (1.0, True), "m/s2": (1.0, True), "m/s": (1.0, False)}
GYRO_UNITS = {"rad/s": (1.0, True), "deg/s": (np.pi / 180.0, True), "rad": (1.0, False), "deg": (np.pi / 180.0, False)}
TIME_SCALES = ("gpst_unix", "gps_sow", "gps_abs", "utc_unix")
AXES = ("ax", "ay", "az", "gx", "gy", "gz")


@dataclass
class ImuData:
    """Increments in the IMU's own axes, each over the interval ending at t_abs."""

    t_abs: np.ndarray  # (n,) GPS seconds since the GPS epoch
    dtheta_rad: np.ndarray  # (n, 3)
    dv_mps: np.ndarray  # (n, 3)
    source: str = ""
    skipped: Counter = field(default_factory=Counter)
    alignment: dict | None = None  # how the times were found, when not read from a time column
    # Each increment covers the whole step from the previous stamp (rates integrated over it), so a
    # long step is no lost frame for the filter to bridge (its imu_increments_cover_gaps).
    covers_gaps: bool = False

    def __len__(self) -> int:
        return len(self.t_abs)

    def rate_hz(self) -> float:
        return float(1.0 / np.median(np.diff(self.t_abs))) if len(self) > 1 else float("nan")

    def array(self, t0: float = 0.0) -> np.ndarray:
        """The filter's (n, 7) [t - t0, dtheta xyz, dv xyz]."""
        return np.column_stack([self.t_abs - t0, self.dtheta_rad, self.dv_mps])


def to_gps_seconds(t: np.ndarray, scale: str, week: int | None = None, path="<imu>") -> np.ndarray:
    """Time column to GPS seconds since the GPS epoch."""
    if scale == "gpst_unix":  # GPS time counted like Unix time, without leap seconds
        return t - UNIX_TO_GPS_S
    if scale == "gps_abs":
        return t.copy()
    if scale == "utc_unix":
        leap = leap_seconds(dt.datetime(1970, 1, 1) + dt.timedelta(seconds=float(t[0]))) if len(t) else 0
        return t - UNIX_TO_GPS_S + leap
    if scale == "gps_sow":
        if week is None:
            raise ReaderError(path, "time = \"gps_sow\" needs `week = N`", field="week")
        rollover = np.concatenate([[0], np.cumsum(np.diff(t) < -SECONDS_PER_WEEK / 2)])
        return (week + rollover) * SECONDS_PER_WEEK + t
    raise ReaderError(path, f"unknown time scale {scale!r} (one of {', '.join(TIME_SCALES)})", field="time")


def _split(line: str, delimiter: str | None) -> list[str]:
    return line.split(delimiter) if delimiter else line.split()


def _is_row(line: str, delimiter: str | None) -> bool:
    """Whether loadtxt takes a line as a row: with a delimiter, unless it is empty before any #; without one,
    unless it is only blanks."""
    content = line.split("#", 1)[0]
    return bool(content) if delimiter else bool(content.split())


def _data_lines(text: list[str], skip: int, delimiter: str | None) -> list[int]:
    """1-based line numbers of the table's rows as NumPy's loadtxt counts them."""
    return [i for i, line in enumerate(text[skip:], start=skip + 1) if _is_row(line, delimiter)]


def _loadtxt_fails(line: str, delimiter, usecols, comments) -> str:
    """Why loadtxt refuses one line ("" if it takes it)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # an empty line: "input contained no data"
        try:
            np.loadtxt([line], delimiter=delimiter, usecols=usecols, ndmin=2, comments=comments)
        except ValueError as e:
            return str(e).splitlines()[0][:60] if str(e) else "unreadable"
    return ""


def _locate_bad_value(path: Path, text: list[str], usecols, names, delimiter, skip: int) -> ReaderError:
    """The error loadtxt did not place: the first row whose used columns are not all numbers."""
    for i in _data_lines(text, skip, delimiter):
        parts = _split(text[i - 1].split("#", 1)[0], delimiter)
        for c, name in zip(usecols, names):
            try:
                float(parts[c])
            except (ValueError, IndexError):
                got = repr(parts[c].strip()[:20]) if c < len(parts) else "nothing"
                return ReaderError(path, f"{got} is not a number", line=i, field=f"column {c + 1} ({name})")
    for i, line in enumerate(text[skip:], start=skip + 1):  # what float() takes and loadtxt does not ("1_0")
        why = _loadtxt_fails(line, delimiter, usecols, "#")
        if why:
            return ReaderError(path, f"not a row of numbers ({why})", line=i, field="row")
    return ReaderError(path, "unreadable table", line=skip + 1, field="rows")


def _check_layout(path: Path, columns: list, time_column: str, accel_unit: str, gyro_unit: str) -> None:
    missing = [c for c in (time_column, *AXES) if c not in columns]
    if missing:
        raise ReaderError(path, f"columns lack {', '.join(missing)}", field="columns")
    unknown = [c for c in columns if c not in (time_column, "-", *AXES)]
    if unknown:
        raise ReaderError(path, f"unknown column names {unknown}", field="columns")
    if accel_unit not in ACCEL_UNITS:
        raise ReaderError(path, f"unknown accel_unit {accel_unit!r} ({', '.join(ACCEL_UNITS)})", field="accel_unit")
    if gyro_unit not in GYRO_UNITS:
        raise ReaderError(path, f"unknown gyro_unit {gyro_unit!r} ({', '.join(GYRO_UNITS)})", field="gyro_unit")


def _axes_si(col: dict, accel_unit: str, gyro_unit: str) -> tuple[np.ndarray, np.ndarray]:
    # Scaled in place: an hour at 200 Hz is 18 MB a triad.
    acc = np.column_stack([col["ax"], col["ay"], col["az"]])
    acc *= ACCEL_UNITS[accel_unit][0]
    gyr = np.column_stack([col["gx"], col["gy"], col["gz"]])
    gyr *= GYRO_UNITS[gyro_unit][0]
    return acc, gyr


def read(path: str | Path, columns, time: str = "gpst_unix", accel_unit: str = "m/s^2", gyro_unit: str = "rad/s",
         week: int | None = None, delimiter: str | None = None, skip_rows: int | None = None) -> ImuData:
    """Read an IMU table. ``columns``: the leading columns' names in order (t, ax, ay, az, gx, gy, gz;
    "-" skips one; later columns are ignored). ``delimiter``: None guesses (comma if the first data line has one,
    else whitespace). ``skip_rows``: header lines to skip (None: every leading line that is not numeric).
    Rows with a value written as nan or inf are dropped and counted in ``skipped``."""
    path = Path(path)
    columns = list(columns)
    _check_layout(path, columns, "t", accel_unit, gyro_unit)
    # Damaged bytes fail as values, in their line; lines end at LF (CR LF too) only, as loadtxt sees them.
    # Only the head is read here: the table streams from the file (a whole 90 MB file held as bytes
    # was a third of an hour's replay peak), and the whole file is read only for loadtxt's path.
    raw_head = read_head(path, HEAD_BYTES + 1)
    head = raw_head[:HEAD_BYTES]
    if len(raw_head) > HEAD_BYTES:
        head = head[:head.rfind(b"\n") + 1]
    head = [x.rstrip("\r") for x in head.decode("utf-8", errors="replace").split("\n")[:1000]]
    if skip_rows is None:
        skip_rows = 0
        number = re.compile(r"^\s*[-+]?(\d|\.\d)")
        while skip_rows < len(head) and not number.match(head[skip_rows]):
            skip_rows += 1
    if skip_rows >= len(head):
        raise ReaderError(path, "no data rows (no line starts with a number)", line=len(head) + 1, field="rows")
    if delimiter is None:
        delimiter = "," if "," in head[skip_rows] else None
    names = [c for c in columns if c != "-"]
    usecols = [k for k, c in enumerate(columns) if c != "-"]
    start = _byte_after_lines(raw_head, skip_rows)
    body = raw_head[start:]
    row_bytes = max(8.0, len(body) / max(1, body.count(b"\n")))
    a = _read_table_fast(path, start, delimiter, usecols, row_bytes)
    lines = None
    if a is None:
        data = read_bytes(path)
        lines = [x.rstrip("\r") for x in data.decode("utf-8", errors="replace").split("\n")]
        del data
        try:  # NumPy's C parser; the slow scan below only to name a bad value
            a = np.loadtxt(lines[skip_rows:], delimiter=delimiter, usecols=usecols, ndmin=2, comments="#")
        except ValueError:
            raise _locate_bad_value(path, lines, usecols, names, delimiter, skip_rows) from None
    if not len(a):
        raise ReaderError(path, "no data rows", line=skip_rows + 1, field="rows")
    skipped = Counter()
    ok = finite_rows(a)
    if not ok.all():
        skipped[f"IMU {NON_FINITE_ROWS}"] = int((~ok).sum())
        a = a[ok]
        if not len(a):
            raise ReaderError(path, "every row has a value written as nan or inf", line=skip_rows + 1, field="rows")
    col = {n: a[:, k] for k, n in enumerate(names)}
    try:
        t = to_gps_seconds(col["t"], time, week, path)
    except (OverflowError, ValueError) as e:  # utc_unix: a time no calendar has, for the leap seconds
        if isinstance(e, ReaderError):
            raise
        lines = lines or [x.rstrip("\r") for x in read_bytes(path).decode("utf-8", errors="replace").split("\n")]
        rows = np.asarray(_data_lines(lines, skip_rows, delimiter))
        raise ReaderError(path, f"time {col['t'][0]!r} is no {time} time ({e})",
                          line=int(rows[ok][0]) if len(rows) == len(ok) else skip_rows + 1, field="t") from None
    acc, gyr = _axes_si(col, accel_unit, gyro_unit)
    return from_samples(t, acc, gyr, accel_unit, gyro_unit, path.name, skipped)


# The table is parsed in pieces of about this many bytes, each cut at a line end: pyarrow's own streaming
# reader buffered most of a 90 MB file ahead of its parser.
PIECE_BYTES = 1 << 23


def _byte_after_lines(head: bytes, lines: int) -> int:
    """Where the line after the first ``lines`` lines of the head starts."""
    start = 0
    for _ in range(lines):
        start = head.find(b"\n", start) + 1
    return start


def _pieces(path: Path, start: int):
    """The file's bytes from ``start`` on, in pieces of whole lines (the last one as it ends)."""
    opener = gzip.open if path.suffix.lower() == ".gz" else open
    with opener(path, "rb") as f:
        f.seek(start)
        rest = b""
        while True:
            chunk = f.read(PIECE_BYTES)
            if not chunk:
                if rest.strip():  # pyarrow takes a lone last line only with its line end
                    yield rest + b"\n"
                return
            buf = rest + chunk
            cut = buf.rfind(b"\n") + 1
            if cut:
                yield buf[:cut]
            rest = buf[cut:]


def _read_table_fast(path: Path, start: int, delimiter: str | None, usecols: list[int],
                     row_bytes: float = 24.0) -> np.ndarray | None:
    """The used columns of a delimited table from byte ``start`` of the file on, by pyarrow's CSV reader
    (threaded: 0.30 s for a 64 MB file where loadtxt takes 0.89 s, the same doubles), piece by piece into
    the array NumPy keeps, or None where loadtxt is to read it: whitespace columns, comments, or anything
    pyarrow refuses (loadtxt then refuses it too, or reads what pyarrow does not: the slow path names a
    bad value). A '#' in a used column is a value pyarrow refuses; in an unused one loadtxt would drop
    the rest of the line, which holds no used value either."""
    if delimiter is None or len(delimiter) != 1:
        return None
    import pyarrow as pa
    import pyarrow.csv as pa_csv

    names = [f"f{k}" for k in usecols]
    read = pa_csv.ReadOptions(autogenerate_column_names=True, block_size=1 << 20)
    parse = pa_csv.ParseOptions(delimiter=delimiter, quote_char=False)
    convert = pa_csv.ConvertOptions(include_columns=names, column_types=dict.fromkeys(names, pa.float64()),
                                    null_values=[], strings_can_be_null=False)
    # Rows by the head's line length (a compressed file's size says less: grown as needed).
    out = np.empty((max(1024, int(1.02 * (path.stat().st_size - start) / row_bytes) + 1), len(names)))
    n = 0
    try:
        for piece in _pieces(path, start):
            table = pa_csv.read_csv(pa.py_buffer(piece), read_options=read, parse_options=parse,
                                    convert_options=convert, memory_pool=pa.system_memory_pool())
            rows = table.num_rows
            if n + rows > len(out):
                out.resize((max(2 * len(out), n + rows), len(names)), refcheck=False)
            for k, name in enumerate(names):
                out[n:n + rows, k] = table.column(name).to_numpy()
            n += rows
    except (pa.ArrowInvalid, pa.ArrowKeyError, KeyError):
        return None
    if not n:
        return None
    out.resize((n, len(names)), refcheck=False)  # in place: no second copy of the table
    return out


@dataclass
class CounterRows:
    """An IMU stream logged raw, time-stamped by its own sample counter (``columns`` with "counter" instead of
    "t"): the rows in SI units and where each line ends in the file, for the logger's arrival times."""

    counter: np.ndarray  # (n,) the sensor's counter, unwrapped
    acc: np.ndarray  # (n, 3) SI
    gyr: np.ndarray  # (n, 3) SI
    end_offset: np.ndarray  # (n,) file offset after each row's line end
    line_no: np.ndarray  # (n,) 1-based line number
    file_bytes: int
    newlines: int  # line ends in the file
    skipped: Counter = field(default_factory=Counter)


def read_counter_rows(path: str | Path, columns, accel_unit: str = "m/s^2", gyro_unit: str = "rad/s",
                      delimiter: str | None = None, counter_bits: int = 32) -> CounterRows:
    """Rows of a raw logged stream; lines with too few fields are skipped and counted, every whole one kept.
    The counter wraps at 2^counter_bits."""
    path = Path(path)
    columns = list(columns)
    _check_layout(path, columns, "counter", accel_unit, gyro_unit)
    data = read_bytes(path)
    lines = data.split(b"\n")
    ends = np.cumsum([len(x) + 1 for x in lines])
    if not data.endswith(b"\n"):
        ends[-1] -= 1  # the last line has no line end
    sep = (b"," if b"," in data[:4096] else None) if delimiter is None else delimiter.encode()
    width = len(columns)
    # The logger may have started and stopped mid-line: the first line and an unterminated last one can be
    # cut anywhere, even between digits, so they are never used.
    whole = range(1, len(lines) - 1)
    kept = [i for i in whole if lines[i].strip() and len(lines[i].split(sep)) >= width]
    skipped = Counter()
    if lines[0].strip() or lines[-1].strip():
        skipped["IMU lines at the ends of the stream (a logger starts and stops mid-line)"] = \
            bool(lines[0].strip()) + bool(lines[-1].strip())
    short = sum(1 for i in whole if lines[i].strip()) - len(kept)
    if short:
        skipped["IMU lines with too few fields"] = short
    if not kept:
        raise ReaderError(path, f"no whole line of {width} fields between the stream's first and last line",
                          line=1, field="rows")
    use = [k for k, c in enumerate(columns) if c != "-"]
    text = [lines[i].rstrip(b"\r").decode("ascii", "replace") for i in kept]
    delim = sep.decode("ascii", "replace") if sep else None
    try:  # NumPy's C parser; the scan below only to name a bad value
        a = np.loadtxt(text, delimiter=delim, usecols=use, ndmin=2, comments=None)
    except ValueError:
        raise _locate_bad_raw_value(path, lines, kept, sep, use, columns) from None
    ok = finite_rows(a)
    if not ok.all():
        skipped["IMU lines with a value written as nan or inf (dropped)"] = int((~ok).sum())
        a, kept = a[ok], [i for i, good in zip(kept, ok) if good]
        if not kept:
            raise ReaderError(path, "every line has a value written as nan or inf", line=1, field="rows")
    col = {columns[k]: a[:, j] for j, k in enumerate(use)}
    raw = col["counter"]
    wrong = np.flatnonzero((raw != np.round(raw)) | (raw < 0) | (raw >= 2.0 ** counter_bits))
    if len(wrong):
        k = int(wrong[0])
        raise ReaderError(path, f"{raw[k]!r} is no {counter_bits}-bit sample count", line=kept[k] + 1,
                          field="counter")
    counter = raw.astype(np.int64)
    counter += np.concatenate([[0], np.cumsum(np.diff(counter) < -(1 << (counter_bits - 1)))]) << counter_bits
    back = np.flatnonzero(np.diff(counter) <= 0)
    if len(back):
        raise ReaderError(path, f"the counter does not increase ({counter[back[0]]} then {counter[back[0] + 1]}): "
                          "a sensor restart? one continuous counter per file", line=kept[back[0] + 1] + 1,
                          field="counter")
    acc, gyr = _axes_si(col, accel_unit, gyro_unit)
    kept = np.asarray(kept, int)
    return CounterRows(counter, acc, gyr, ends[kept], kept + 1, len(data), data.count(b"\n"), skipped)


def _locate_bad_raw_value(path: Path, lines: list[bytes], kept: list[int], sep, use, columns) -> ReaderError:
    delimiter = sep.decode("ascii", "replace") if sep else None
    for i in kept:
        parts = lines[i].rstrip(b"\r").split(sep)
        for k in use:
            try:
                float(parts[k])
            except ValueError:
                return ReaderError(path, f"not a number: {parts[k][:20].decode('ascii', 'replace')!r}", line=i + 1,
                                   field=columns[k])
    for i in kept:  # what float() takes and loadtxt does not ("1_0")
        why = _loadtxt_fails(lines[i].rstrip(b"\r").decode("ascii", "replace"), delimiter, use, None)
        if why:
            return ReaderError(path, f"not a row of numbers ({why})", line=i + 1, field="row")
    return ReaderError(path, "unreadable rows", line=(kept[0] + 1) if kept else 1, field="rows")


def from_samples(t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, accel_unit: str, gyro_unit: str,
                 source: str = "", skipped: Counter | None = None) -> ImuData:
    """Samples in SI units (rates or increments as their units say) at GPS times to increments."""
    skipped = Counter(skipped or {})
    # Column by column and copied only where a sample goes: the arrays are the run's largest.
    bad = ~(np.isfinite(t) & finite_rows(acc) & finite_rows(gyr))
    if bad.any():  # before the time order: a NaN time would hide every later one
        skipped["IMU samples with a non-finite value"] = int(bad.sum())
        t, acc, gyr = t[~bad], acc[~bad], gyr[~bad]
    # Keep samples whose time increases over the last kept one (a stamp that goes back is a glitch).
    keep = np.ones(len(t), bool)
    if len(t) > 1:
        run_max = np.maximum.accumulate(t)
        keep[1:] = t[1:] > run_max[:-1]
        del run_max
    if not keep.all():
        skipped["IMU samples whose time does not increase"] = int((~keep).sum())
        t, acc, gyr = t[keep], acc[keep], gyr[keep]
    accel_rates, gyro_rates = ACCEL_UNITS[accel_unit][1], GYRO_UNITS[gyro_unit][1]
    dv = _increments(t, acc, accel_rates)
    dth = _increments(t, gyr, gyro_rates)
    if accel_rates or gyro_rates:
        t = t[1:]
        if not accel_rates:
            dv = dv[1:]
        if not gyro_rates:
            dth = dth[1:]
    return ImuData(t, dth, dv, source, skipped, covers_gaps=accel_rates and gyro_rates)


def _increments(t: np.ndarray, x: np.ndarray, rates: bool) -> np.ndarray:
    if not rates:
        return x
    dt = np.diff(t)[:, None]
    return 0.5 * (x[1:] + x[:-1]) * dt
