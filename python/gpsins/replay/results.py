"""A replay's results on disk: per-epoch tables written chunk by chunk, and read back.

A results directory holds

- ``solution.parquet``: the forward solution, one row per output epoch (see
  ``replay.summary.RESULT_ARRAYS`` for what each array is);
- ``smoothed.parquet`` (``--smooth``): the fixed-interval smoothed solution, same epochs;
- ``updates.parquet``: one row per measurement update;
- ``covariance.parquet`` (``--covariance-every N``): the full error-state covariance of every
  Nth epoch, upper triangle by rows;
- ``results.npz``: what is small whatever the session length: the receiver's fixes, the
  outage schedule, the truth's segments, the scoring against a reference.

Why Parquet: replay writes row groups as the filter produces its chunks, so memory does not
grow with the session; pandas (``pandas.read_parquet``), pyarrow, polars and DuckDB open it
directly; it is columnar, so a plot reads only its columns; and it compresses. An array of
several columns (``r_ecef``: x, y, z) is stored as one column per component
(``r_ecef_x`` ...); the file's metadata names them so that ``load`` gives the array back.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

def plain(x):
    """JSON-ready: arrays to lists, NumPy scalars to Python's, non-finite numbers to null."""
    if isinstance(x, dict):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return plain(x.tolist())
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, (np.integer, int)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    return x


def json_text(doc, indent: int = 2) -> str:
    """Strict JSON (RFC 8259: no NaN or Infinity) of a document that may hold NumPy values."""
    return json.dumps(plain(doc), indent=indent, allow_nan=False)


SOLUTION = "solution.parquet"
SMOOTHED = "smoothed.parquet"
UPDATES = "updates.parquet"
COVARIANCE = "covariance.parquet"
SMALL = "results.npz"
SMOOTH_PREFIX = "smooth_"  # load(): the smoothed solution's arrays, as results.npz had them
_META_KEY = b"gpsins:arrays"
# Dictionary encoding costs two thirds of the write time and gains nothing on measured floats.
_WRITE_OPTIONS = dict(compression="zstd", compression_level=1, use_dictionary=False)

# Component names of multi-column arrays; anything else is numbered (sigma_0, sigma_1, ...).
_XYZ, _NED, _YPR = ("x", "y", "z"), ("n", "e", "d"), ("yaw", "pitch", "roll")
COMPONENTS = {"r_ecef": _XYZ, "v_ecef": _XYZ, "gyro_bias": _XYZ, "accel_bias": _XYZ, "r_point_ecef": _XYZ,
              "fix_error": _XYZ, "q_eb": ("w", "x", "y", "z"), "llh": ("lat_rad", "lon_rad", "h_m"), "ypr_deg": _YPR,
              "sigma_ned_m": _NED, "sigma_v_ned_mps": _NED, "sigma_ypr_deg": ("n", "e", "d"),
              "err_ned_m": _NED, "err_v_ned_mps": _NED, "err_ypr_deg": _YPR, "clock": ("bias_m", "drift_mps"),
              "innovation": ("0", "1", "2"), "innovation_sigma": ("0", "1", "2")}


def _pa():
    import pyarrow as pa
    import pyarrow.parquet as pq
    return pa, pq


def _columns(arrays: dict) -> tuple[dict, dict]:
    """Flat columns and the metadata that gives the arrays back."""
    cols, meta = {}, {}
    for name, a in arrays.items():
        a = np.asarray(a)
        if a.ndim == 1:
            cols[name] = a
            continue
        a = a.reshape(a.shape[0], int(np.prod(a.shape[1:])))
        parts = COMPONENTS.get(name)
        if parts is None or len(parts) != a.shape[1]:
            parts = tuple(str(i) for i in range(a.shape[1]))
        names = [f"{name}_{p}" for p in parts]
        cols.update({c: np.ascontiguousarray(a[:, i]) for i, c in enumerate(names)})
        meta[name] = names
    return cols, meta


ROW_GROUP_BYTES = 16 << 20  # chunks are gathered into row groups of about this much column data


class TableWriter:
    """A Parquet file written as the chunks come; the first chunk fixes the columns.

    Chunks are gathered into row groups of about ``group_bytes``: the writer keeps every row
    group's metadata until it closes and then writes it out, about 65 kB per row group for a
    solution table, so a row group per 4096-row chunk would grow by 90 MB over a day at 64 Hz,
    and again as much when closed. ``newest_first``: chunks arrive newest first (the smoother's)
    and each row group holds its chunks in time order, so reversing the row groups
    (``reverse_row_groups``) puts the whole file in time order."""

    def __init__(self, path: Path, newest_first: bool = False, group_bytes: int = ROW_GROUP_BYTES):
        self.path = Path(path)
        self.newest_first = newest_first
        self.group_bytes = group_bytes
        self._writer = None
        self._schema = None
        self._pending: list = []
        self._pending_bytes = 0
        self.rows = 0

    def append(self, arrays: dict) -> None:
        pa, pq = _pa()
        cols, meta = _columns(arrays)
        if self._writer is None:
            table = pa.table(cols)
            self._schema = table.schema.with_metadata({_META_KEY: json.dumps(meta).encode()})
            self._writer = pq.ParquetWriter(self.path, self._schema, **_WRITE_OPTIONS)
        table = pa.table(cols, schema=self._schema)
        if table.num_rows:
            self._pending.append(table)
            self._pending_bytes += table.nbytes
            self.rows += table.num_rows
            if self._pending_bytes >= self.group_bytes:
                self._flush()

    def _flush(self) -> None:
        if not self._pending:
            return
        pa, _ = _pa()
        parts = self._pending[::-1] if self.newest_first else self._pending
        table = pa.concat_tables(parts)
        self._pending, self._pending_bytes = [], 0
        try:
            self._writer.write_table(table, row_group_size=table.num_rows)
        except OSError:
            self._give_up()
            raise

    def close(self) -> None:
        if self._writer is not None:
            self._flush()
            try:
                self._writer.close()
            except OSError:
                self._give_up()
                raise
            self._writer = None

    def __del__(self) -> None:
        # Collected unclosed: a run that failed (the results are removed); closing now would only write
        # onto what failed, and its error would print at exit.
        if getattr(self, "_writer", None) is not None:
            self._writer.is_open = False

    def _give_up(self) -> None:
        """A write failed (a full disk): the file is lost; pyarrow must not try to close it again when
        the writer is collected (a second error, printed as an ignored exception at exit)."""
        self._writer.is_open = False
        self._writer = None

    def __enter__(self) -> "TableWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def reverse_row_groups(src: Path, dst: Path) -> None:
    """Copy a Parquet file with its row groups in reverse order (the smoother writes newest first),
    one row group in memory at a time."""
    _, pq = _pa()
    f = pq.ParquetFile(src)
    with pq.ParquetWriter(dst, f.schema_arrow, **_WRITE_OPTIONS) as w:
        for i in reversed(range(f.num_row_groups)):
            w.write_table(f.read_row_group(i))
    f.close()
    Path(src).unlink()


def read_table(path: str | Path, columns=None, stride: int = 1) -> dict:
    """A table's arrays as replay wrote them (multi-column ones put back together), every
    ``stride``-th row; ``columns`` selects arrays by name."""
    _, pq = _pa()
    f = pq.ParquetFile(path)
    meta = json.loads((f.schema_arrow.metadata or {}).get(_META_KEY, b"{}"))
    flat = set(f.schema_arrow.names) - {c for cs in meta.values() for c in cs}
    names = (list(flat) + list(meta)) if columns is None else [c for c in columns if c in flat or c in meta]
    want = [c for n in names for c in meta.get(n, [n])]
    out: dict = {n: [] for n in names}
    offset = 0
    for i in range(f.num_row_groups):  # a row group at a time: decimation keeps memory small
        t = f.read_row_group(i, columns=want)
        pick = slice((-offset) % stride, None, stride)
        for n in names:
            parts = [t.column(c).to_numpy() for c in meta.get(n, [n])]
            out[n].append(np.column_stack(parts)[pick] if n in meta else parts[0][pick])
        offset += t.num_rows
    f.close()
    return {n: (np.concatenate(v) if v else np.zeros((0, len(meta.get(n, [n]))) if n in meta else 0))
            for n, v in out.items()}


def exists(path: str | Path) -> bool:
    p = Path(path)
    return (p / SOLUTION).is_file() and (p / SMALL).is_file()


def load(path: str | Path, stride: int = 1) -> dict:
    """Everything a results directory holds as one dict of arrays (the names of ``replay.summary.RESULT_ARRAYS``;
    the smoothed solution's with the prefix ``smooth_``, updates with ``upd_``), per-epoch arrays every
    ``stride``-th epoch."""
    p = Path(path)
    with np.load(p / SMALL) as z:
        out = {k: z[k] for k in z.files}
    out.update(read_table(p / SOLUTION, stride=stride))
    if (p / SMOOTHED).is_file():
        out.update({SMOOTH_PREFIX + k: v for k, v in read_table(p / SMOOTHED, stride=stride).items()})
    if (p / UPDATES).is_file():
        out.update({"upd_" + k: v for k, v in read_table(p / UPDATES).items()})
    return out


def epochs(path: str | Path) -> int:
    """Rows of a results directory's solution table."""
    _, pq = _pa()
    return pq.ParquetFile(Path(path) / SOLUTION).metadata.num_rows


def load_covariance(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(t, (n, N, N) covariances) of ``covariance.parquet``."""
    a = read_table(Path(path) / COVARIANCE)
    upper = a["p_upper"]
    n_states = int(round((np.sqrt(8 * upper.shape[1] + 1) - 1) / 2))
    p = np.zeros((len(upper), n_states, n_states))
    i, j = np.triu_indices(n_states)
    p[:, i, j] = upper
    p[:, j, i] = upper
    return a["t"], p


def covariance_columns(t: np.ndarray, cov: np.ndarray) -> dict:
    i, j = np.triu_indices(cov.shape[-1])
    return {"t": t, "p_upper": cov[:, i, j]}
