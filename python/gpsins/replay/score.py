"""Solutions computed elsewhere, scored as a replay's (``gpsins score SOLUTION --against SOURCE``).

The solution file is read (an RTKLIB .pos, KF-GINS's navigation result, a CSV with declared columns)
and handed to the replay as
a plug-in estimator that returns it, so its run.json, drift per outage, errors against a truth and
report pages are made by the same code as a replay's. ``point``: where the solution is, the antenna
(an RTKLIB solution; scored with no lever arm, so against the reference as it is) or the IMU (KF-GINS).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..formats import gpstime
from . import run
from . import inputs as replay_inputs
from ..formats import kfgins, rtklib_pos, solution_csv

FORMATS = ("pos", "kf-gins", "csv")


class ScoreError(ValueError):
    pass


def read_solution(path: str | Path, fmt: str | None = None, columns: list[str] | None = None,
                  time: str = "gps_abs", week: int | None = None) -> dict:
    """t_abs, r_ecef, v_ecef (NaN where the file has none) and q_eb (NaN likewise) of a solution file;
    ``columns``, ``time``, ``week``: a CSV's (``formats.solution_csv``)."""
    path = Path(path)
    fmt = fmt or ("pos" if path.suffix.lower() == ".pos" else "csv" if columns else "kf-gins")
    if fmt not in FORMATS:
        raise ScoreError(f"{path}: --format {fmt!r}: one of {', '.join(FORMATS)}")
    if fmt == "csv":
        if not columns:
            raise ScoreError(f"{path}: --format csv needs --columns (e.g. t,lat_deg,lon_deg,h_m)")
        return solution_csv.read(path, columns, time, week)
    if fmt == "kf-gins":
        return kfgins.read_nav(path)
    f = rtklib_pos.read(path)
    return {"t_abs": f.t_abs, "r_ecef": f.r_ecef, "v_ecef": f.v_ecef(), "q_eb": np.full((len(f), 4), np.nan)}


def _as_estimator(sol: dict, name: str):
    def solution_file(inputs):
        t = sol["t_abs"] - inputs.week * gpstime.SECONDS_PER_WEEK
        keep = np.concatenate([[True], np.diff(t) > 0])  # a time written twice (rounded) counts once
        return {k: sol[k][keep] for k in ("r_ecef", "v_ecef", "q_eb")} | {"t": t[keep]}

    solution_file.__name__ = name
    return solution_file


def score(solution: str | Path, against: str | Path, out: str | Path, *, fmt: str | None = None,
          point: str | None = None, outages=None, reference=None, reference_q=(1,), columns=None,
          time: str = "gps_abs", week: int | None = None) -> run.ReplayResult:
    """Score a solution file against a session or a data set (its truth, reference and outages)."""
    sol = read_solution(solution, fmt, columns, time, week)
    point = point or ("antenna" if Path(solution).suffix.lower() == ".pos" else "imu")
    if point not in ("antenna", "imu"):
        raise ScoreError(f"--point {point!r}: antenna or imu")
    inp = replay_inputs.load_inputs(against, force=True)
    # At the antenna the solution is where the reference is: no lever arm between them.
    overrides = {"lever_arm_body_m": [0.0, 0.0, 0.0]} if point == "antenna" else {}
    return run.run_mode(inp, out, mode="loose", overrides=overrides, outages=outages, reference=reference,
                        reference_q=reference_q, point=point,
                        estimator=_as_estimator(sol, f"file {Path(solution).name}"))
