"""A filter solution on its way to disk, a chunk of epochs at a time.

``Stream`` takes the filter's output chunk by chunk (``nav.runs.ChunkedRun``): it works out what
a user looks at for each epoch (geodetic position, Euler angles, NED sigmas, the antenna's
position, and with a simulated truth the errors and the 9-state NEES), appends them to the
results table (``results.TableWriter``), writes the RTKLIB-style ``.pos`` lines, and keeps
running statistics, so nothing held grows with the session but the few solution rows that
bracket a reference epoch (``Brackets``). The smoothed solution arrives newest block first;
the same ``Stream`` puts it back in time order at the end.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import _core, evaluate
from ..nav import runs as flt
from . import results
from ..formats.gpstime import SECONDS_PER_WEEK

POS_HEADER = ("% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)\n"
              "%  GPST                   latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)"
              "  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio\n")


def nav_sigmas(sol: flt.Solution, llh: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position (m), velocity (m/s) and attitude (deg, about N, E, D) sigmas in local NED."""
    c_en = evaluate.c_en(llh[:, 0], llh[:, 1])
    p = sol.covariance
    # Only the diagonal of C^T P C is wanted: sum_j C_ji (P C)_ji, one product instead of two.
    sigma = lambda c, block: np.sqrt(np.einsum("nji,nji->ni", c, block @ c))  # noqa: E731
    # Body-side attitude error dtheta -> NED axes: C_nb dtheta, so C = C_bn.
    c_bn = np.swapaxes(_core.dcm_from_quat(sol.q_eb), -1, -2) @ c_en
    return sigma(c_en, p[:, 6:9, 6:9]), sigma(c_en, p[:, 3:6, 3:6]), np.degrees(sigma(c_bn, p[:, 0:3, 0:3]))


def antenna_positions(sol: flt.Solution, lever_arm_body_m) -> np.ndarray:
    """ECEF position of the antenna: r + C_eb lever arm."""
    lever = np.broadcast_to(np.asarray(lever_arm_body_m, float), (3,))
    if not np.any(lever) or not len(sol.t):
        return sol.r_ecef.copy()
    return sol.r_ecef + _core.dcm_from_quat(sol.q_eb) @ lever


def epoch_arrays(sol: flt.Solution) -> dict:
    """A chunk's per-epoch arrays as the results table holds them (without truth errors)."""
    llh = sol.llh()
    sigma_ned, sigma_v_ned, sigma_ypr = nav_sigmas(sol, llh)
    a = dict(t=sol.t, r_ecef=sol.r_ecef, v_ecef=sol.v_ecef, q_eb=sol.q_eb, llh=llh,
             ypr_deg=np.degrees(_core.euler_from_body_to_ecef(sol.q_eb, llh)), gyro_bias=sol.gyro_bias,
             accel_bias=sol.accel_bias, sigma=sol.sigma, sigma_ned_m=sigma_ned, sigma_ypr_deg=sigma_ypr,
             sigma_v_ned_mps=sigma_v_ned, standstill=sol.standstill, heading_known=sol.heading_known)
    if sol.clock is not None:
        a["clock"] = sol.clock
    if getattr(sol, "fix_error", None) is not None:
        a["fix_error"] = sol.fix_error
    if getattr(sol, "time_offset", None) is not None:
        a["time_offset_s"] = sol.time_offset
    return a


@dataclass
class TruthScore:
    """Errors against the simulator's truth per epoch (NaN outside the truth's span), and their
    statistics from the first known heading on, accumulated chunk by chunk."""

    truth: evaluate.Truth
    n: int = 0
    sum_h2: float = 0.0
    sum_v2: float = 0.0
    max_h: float = 0.0
    max_v: float = 0.0
    sum_nees: float = 0.0
    inside: int = 0

    def errors(self, sol: flt.Solution) -> dict:
        tr = self.truth
        m = (sol.t >= tr.t[0]) & (sol.t <= tr.t[-1])
        whole = bool(m.all())  # as a rule: then no copies of the chunk
        sub = sol if whole else _subset(sol, m)
        err = evaluate.nav_errors(sub, tr)
        # The navigation block only: masking the whole covariance first copied it (tight: ~50 states).
        p9 = sol.covariance[:, :9, :9]
        nees = evaluate.nees(err.e9, p9 if whole else p9[m])
        tr.release()  # a memory-mapped truth: only this chunk's rows were read; keep none of them
        hk = sub.heading_known
        if hk.any():
            h = np.hypot(err.r_ned[hk, 0], err.r_ned[hk, 1])
            v = err.r_ned[hk, 2]
            self.n += int(hk.sum())
            self.sum_h2 += float(np.sum(h ** 2))
            self.sum_v2 += float(np.sum(v ** 2))
            self.max_h = max(self.max_h, float(h.max()))
            self.max_v = max(self.max_v, float(np.abs(v).max()))
            self.sum_nees += float(nees[hk].sum())
            self.inside += int(np.sum(np.abs(err.e9[hk]) <= 3 * sub.sigma[hk, :9]))
        return dict(err_ned_m=_fill(m, err.r_ned), err_ypr_deg=_fill(m, err.ypr_deg),
                    err_v_ned_mps=_fill(m, err.v_ned), nees9=_fill(m, nees))

    def summary(self) -> dict:
        """The run's statistics (none if a short or standing run never knew its heading)."""
        if not self.n:
            return {}
        return {"horizontal_rms_m": float(np.sqrt(self.sum_h2 / self.n)), "horizontal_max_m": self.max_h,
                "vertical_rms_m": float(np.sqrt(self.sum_v2 / self.n)), "vertical_max_m": self.max_v,
                "nees9_mean": self.sum_nees / self.n, "inside_3_sigma": self.inside / (9 * self.n)}


class Brackets:
    """The solution rows that bracket given epochs (a reference's), from chunks in any order:
    linear interpolation at those epochs then gives what it gives on the whole solution. Each
    chunk's first and last rows are kept too, so brackets across chunk boundaries are found.

    Rows go into column blocks of ``BLOCK_ROWS`` (a day at 10 Hz keeps millions: many small
    arrays would be held between the chunks' temporaries and the heap could not give memory
    back); a column given as the very same array as another is kept once."""

    BLOCK_ROWS = 1 << 18

    def __init__(self, epochs: np.ndarray):
        self.epochs = np.unique(np.asarray(epochs, float))
        self._blocks: list[dict] = []
        self._fill = 0  # rows used in the last block
        self._alias: dict[str, str] = {}

    def add(self, t: np.ndarray, **arrays) -> None:
        if not len(t) or not len(self.epochs):
            return
        inside = self.epochs[(self.epochs >= t[0]) & (self.epochs <= t[-1])]
        i = np.clip(np.searchsorted(t, inside, side="right") - 1, 0, len(t) - 1)
        keep = np.unique(np.concatenate([[0, len(t) - 1], i, np.minimum(i + 1, len(t) - 1)]))
        cols, alias = {"t": t[keep]}, {}
        for k, v in arrays.items():
            same = next((j for j in cols if j != "t" and arrays[j] is v), None)
            if same is None:
                cols[k] = v[keep]
            else:
                alias[k] = same
        if self._blocks and alias != self._alias:
            raise ValueError("Brackets: the same columns must be the same arrays in every chunk")
        self._alias = alias
        self._append(cols)

    def _append(self, cols: dict) -> None:
        n, at = len(cols["t"]), 0
        while at < n:
            if not self._blocks or self._fill == len(self._blocks[-1]["t"]):
                # The first block holds two rows per epoch and a few chunk ends: usually all there is (only
                # the pages written become resident), so that rows() needs no copy.
                rows = self.BLOCK_ROWS if self._blocks else 2 * len(self.epochs) + self.BLOCK_ROWS
                self._blocks.append({k: np.empty((rows,) + v.shape[1:], v.dtype) for k, v in cols.items()})
                self._fill = 0
            block = self._blocks[-1]
            m = min(n - at, len(block["t"]) - self._fill)
            for k, v in cols.items():
                block[k][self._fill:self._fill + m] = v[at:at + m]
            self._fill += m
            at += m

    def rows(self) -> dict:
        """The kept rows in time order, each epoch once (then kept as one block)."""
        if not self._blocks:
            return {}
        if len(self._blocks) == 1:
            self._blocks[0] = {k: v[:self._fill] for k, v in self._blocks[0].items()}  # views: no copy
            t = self._blocks[0]["t"]
            if len(t) > 1 and not np.all(t[1:] > t[:-1]):  # out of order or repeated (smoothed blocks)
                _, first = np.unique(t, return_index=True)
                self._blocks[0] = {k: v[first] for k, v in self._blocks[0].items()}
            self._fill = len(self._blocks[0]["t"])
        if len(self._blocks) > 1:
            blocks, self._blocks = self._blocks, []
            sizes = [len(b["t"]) for b in blocks[:-1]] + [self._fill]
            cat = {k: np.empty((sum(sizes),) + v.shape[1:], v.dtype) for k, v in blocks[0].items()}
            at = 0
            for i, size in enumerate(sizes):  # each block dropped once copied
                b, blocks[i] = blocks[i], None
                for k, v in b.items():
                    cat[k][at:at + size] = v[:size]
                at += size
            t = cat["t"]
            if len(t) > 1 and not np.all(t[1:] > t[:-1]):  # out of order or repeated (smoothed blocks)
                _, first = np.unique(t, return_index=True)
                cat = {k: v[first] for k, v in cat.items()}
            self._blocks, self._fill = [cat], len(cat["t"])
        out = dict(self._blocks[0])
        out.update({k: out[j] for k, j in self._alias.items()})
        return out


class PosWriter:
    """RTKLIB-style .pos lines (lat/lon/height, GPST epochs; Q = 5, single, for an INS solution)
    appended a chunk at a time; ``reversed_blocks``: chunks come newest first and are put back
    in time order by ``close``."""

    def __init__(self, path: Path, week: int, note: str, reversed_blocks: bool = False):
        self.path, self.week, self.reversed = Path(path), week, reversed_blocks
        self._tmp = self.path.with_name(self.path.name + ".part") if reversed_blocks else self.path
        self._f = open(self._tmp, "wb")
        self._blocks: list[tuple[int, int]] = []  # (offset, length) of each block in the part file
        if not reversed_blocks:
            self._f.write(self._header(note).encode("ascii"))
        self.note = note

    @staticmethod
    def _header(note: str) -> str:
        return "% program   : gpsins replay\n" + (f"% {note}\n" if note else "%\n") + POS_HEADER

    def add(self, t: np.ndarray, llh: np.ndarray, sigma_ned: np.ndarray, sats: np.ndarray) -> None:
        if not len(t):
            return
        x = self.week * SECONDS_PER_WEEK + np.asarray(t, np.float64)
        whole = np.floor(x)  # to the microsecond, cut to the millisecond (as RTKLIB's own .pos)
        ms = (whole.astype(np.int64) * 1_000_000 + np.round((x - whole) * 1e6).astype(np.int64)) // 1000
        day_ms = np.int64(86_400_000)
        days = ms // day_ms
        date = (np.datetime64("1980-01-06", "D") + days.astype("timedelta64[D]"))
        y = date.astype("datetime64[Y]").astype(np.int64) + 1970
        mo = date.astype("datetime64[M]").astype(np.int64) % 12 + 1
        d = (date - date.astype("datetime64[M]")).astype(np.int64) + 1
        r = ms - days * day_ms
        hh, mm, ss, mmm = r // 3_600_000, r // 60_000 % 60, r // 1000 % 60, r % 1000
        n = len(t)
        llh_deg = np.column_stack([np.degrees(llh[:, 0]), np.degrees(llh[:, 1]), llh[:, 2]])
        sd = np.zeros((n, 6))
        sd[:, :3] = sigma_ned
        q_ns = np.column_stack([np.full(n, 5), np.asarray(sats, np.int64)])
        text = _core.pos_lines(np.column_stack([y, mo, d, hh, mm, ss, mmm]), llh_deg, q_ns, sd, np.zeros((n, 2)))
        if self.reversed:
            self._blocks.append((self._f.tell(), len(text)))
        self._f.write(text)

    def flush(self) -> None:
        """What is written so far readable by another process (a live solution)."""
        self._f.flush()

    def close(self) -> None:
        self._f.close()
        if not self.reversed:
            return
        with open(self._tmp, "rb") as src, open(self.path, "wb") as dst:
            dst.write(self._header(self.note).encode("ascii"))
            for offset, length in reversed(self._blocks):
                src.seek(offset)
                dst.write(src.read(length))
        os.unlink(self._tmp)


@dataclass
class Stream:
    """One solution (forward or smoothed) streamed to a results table and a .pos file.

    truth: a simulated truth to score against; lever: the antenna's lever arm; score_point:
    the point references measure ("antenna" or "imu"); pos_point: the point the .pos gives;
    bracket_epochs: the epochs references are scored at; fix_t / fix_sats: the receiver's fixes
    (the .pos's satellite count); covariance_every: with a path in ``covariance_path``, the full
    covariance of every so many epochs."""

    table: Path
    pos: Path
    week: int
    note: str
    lever: np.ndarray
    fix_t: np.ndarray
    fix_sats: np.ndarray
    truth: evaluate.Truth | None = None
    score_point: str = "antenna"
    pos_point: str = "antenna"
    bracket_epochs: np.ndarray = field(default_factory=lambda: np.zeros(0))
    newest_first: bool = False
    covariance_path: Path | None = None
    covariance_every: int = 0

    def __post_init__(self):
        self._part = self.table.with_name(self.table.name + ".part") if self.newest_first else self.table
        self._writer = results.TableWriter(self._part, newest_first=self.newest_first)
        self._pos = PosWriter(self.pos, self.week, self.note, reversed_blocks=self.newest_first)
        self.score = TruthScore(self.truth) if self.truth is not None else None
        self.brackets = Brackets(self.bracket_epochs)
        self._update_t: list[np.ndarray] = []
        self._cov = None
        if self.covariance_path is not None and self.covariance_every > 0:
            self._cov = results.TableWriter(self.covariance_path)
        self.epochs = 0
        self.first_t = self.last_t = None

    def add(self, sol: flt.Solution, first_index: int = 0) -> None:
        """A chunk of epochs; ``first_index``: the index of its first epoch within the run."""
        if not len(sol.t):
            return
        a = epoch_arrays(sol)
        r_ant = antenna_positions(sol, self.lever)
        r_score = r_ant if self.score_point == "antenna" else sol.r_ecef
        a["r_point_ecef"] = r_score
        if self.score is not None:
            a.update(self.score.errors(sol))
        self._writer.append(a)
        # Velocities only carry a row to a reference epoch within one IMU step: float32 is ample (12 B a row).
        self.brackets.add(sol.t, r_score=r_score, r_imu=sol.r_ecef, v=sol.v_ecef.astype(np.float32),
                          yaw=np.radians(a["ypr_deg"][:, 0]),
                          pitch=np.radians(a["ypr_deg"][:, 1]))
        if len(sol.updates.get("t", ())):  # once per instant: a tight epoch updates each satellite (5 M a day)
            self._update_t.append(np.unique(np.asarray(sol.updates["t"], float)))
        llh_pos = a["llh"] if self.pos_point == "imu" else _core.ecef_to_geodetic(r_ant)
        k = np.clip(np.searchsorted(self.fix_t, sol.t, side="right") - 1, 0, max(len(self.fix_t) - 1, 0))
        sats = self.fix_sats[k] if len(self.fix_t) else np.zeros(len(sol.t), int)
        self._pos.add(sol.t, llh_pos, a["sigma_ned_m"], sats)
        if self._cov is not None:
            idx = np.flatnonzero((first_index + np.arange(len(sol.t))) % self.covariance_every == 0)
            self._cov.append(results.covariance_columns(sol.t[idx], sol.covariance[idx]))
        self.epochs += len(sol.t)
        self.first_t = float(sol.t[0]) if self.first_t is None else min(self.first_t, float(sol.t[0]))
        self.last_t = float(sol.t[-1]) if self.last_t is None else max(self.last_t, float(sol.t[-1]))

    def update_times(self) -> np.ndarray:
        """The instants of the measurement updates so far (where the solution steps), ascending."""
        return np.unique(np.concatenate(self._update_t)) if self._update_t else np.zeros(0)

    def close(self) -> None:
        self._writer.close()
        if self.newest_first and self._part.exists():
            results.reverse_row_groups(self._part, self.table)
        self._pos.close()
        if self._cov is not None:
            self._cov.close()


def _fill(mask: np.ndarray, a: np.ndarray) -> np.ndarray:
    full = np.full((len(mask),) + a.shape[1:], np.nan)
    full[mask] = a
    return full


def _subset(sol: flt.Solution, m: np.ndarray) -> flt.Solution:
    return flt.Solution(sol.mode, sol.n_states, sol.t[m], sol.r_ecef[m], sol.v_ecef[m], sol.q_eb[m], sol.gyro_bias[m],
                        sol.accel_bias[m], sol.sigma[m], sol.standstill[m], sol.heading_known[m], sol.updates,
                        sol.counters)
