"""The report in a terminal: comparison and outage tables (rich).
"""

from __future__ import annotations

import io
import sys
from pathlib import Path


from .data import Result, load_all, stats, receiver_errors, receiver_segment_table, segment_table
from .page import fmt


def comparison_tables(results: list[Result]) -> list:
    """Rich tables for the terminal: the totals, then the errors per segment (Table 6.1 style), a table
    per run and one for the receiver's fixes, each within TERMINAL_WIDTH."""
    from rich.table import Table

    totals = Table(title="Errors vs truth", title_justify="left")
    totals.add_column("")
    for r in results:
        totals.add_column(r.name, justify="right")
    _, rec_e = receiver_errors(results[0])
    rec = stats(rec_e)
    if rec:
        totals.add_column("receiver", justify="right")
    for key, lab, rkey in (("horizontal_rms_m", "H RMS (m)", "h_rms"), ("horizontal_max_m", "H max (m)", "h_max"),
                           ("vertical_rms_m", "V RMS (m)", "v_rms"), ("vertical_max_m", "V max (m)", "v_max"),
                           ("nees9_mean", "mean NEES", None), ("inside_3_sigma", "inside 3 sigma (%)", None)):
        scale = 100.0 if key == "inside_3_sigma" else 1.0
        cells = [fmt(None if (v := (r.run.get("errors") or {}).get(key)) is None else scale * v) for r in results]
        if rec:
            cells.append(fmt(rec.get(rkey)) if rkey else "")
        totals.add_row(lab, *cells)
    tables = [totals] if any(r.run.get("errors") for r in results) else []
    segs = [segment_table(r) for r in results]
    if any(segs):  # one table per run, the receiver's last: side by side they need 140 columns
        rec_rows = receiver_segment_table(results[0])
        tables += [_segment_rich_table(f"{r.name}: errors per segment (Table 6.1)", rows, nees=True)
                   for r, rows in zip(results, segs) if rows]
        if rec_rows:
            sats = {row["segment"]: {k: row[k] for k in ("sats_min", "sats_max")} for row in segs[0]}
            tables.append(_segment_rich_table("receiver fixes: errors per segment (Table 6.1)",
                                              [{**x, **sats.get(x["segment"], {})} for x in rec_rows], nees=False))
    return tables


def _segment_rich_table(title: str, rows: list[dict], nees: bool):
    """One run's errors per segment: RMS (max) horizontal and vertical, and its mean NEES."""
    from rich.table import Table

    t = Table(title=title, title_justify="left")
    for name in ("segment", "sats", "H RMS (max), m", "V RMS (max), m") + (("NEES",) if nees else ()):
        t.add_column(name, justify="left" if name == "segment" else "right")
    for row in rows:
        sats = f"{row['sats_min']}-{row['sats_max']}" if "sats_min" in row else ""
        t.add_row(row["segment"], sats, f"{fmt(row.get('h_rms'))} ({fmt(row.get('h_max'))})",
                  f"{fmt(row.get('v_rms'))} ({fmt(row.get('v_max'))})",
                  *([fmt(row.get("nees9_mean"))] if nees else []))
    return t


def outage_table(summary: dict, title: str | None = None):
    """A rich table of one run's drift per outage and the statistics (from run.json's ``scoring``),
    with the smoothed solution's beside the forward one's when the run was smoothed."""
    from rich.table import Table

    sc = summary["scoring"]
    sm = (summary.get("smoothed") or {}).get("scoring")
    if sm is not None and len(sm.get("per_outage", ())) != len(sc["per_outage"]):
        sm = None
    t = Table(title=title or f"{summary.get('mode', '')}: drift against {Path(sc['reference']).name} "
              f"({sc['point']} point), m", title_justify="left",
              caption="from, to: s since the first GNSS epoch", caption_justify="left")
    names = ["outage", "from (s)", "to (s)", "ref epochs", "max H", "max V"]
    names += ["smooth H", "smooth V"] if sm is not None else []
    for name in names:
        t.add_column(name, justify="left" if name == "outage" else "right")
    both = lambda cells, s_cells: cells + (s_cells if sm is not None else [])  # noqa: E731
    t0 = summary["outages"].get("gnss_first_t", 0.0)  # the schedule's origin: the first GNSS epoch
    for j, o in enumerate(sc["per_outage"]):
        s_o = sm["per_outage"][j] if sm is not None else {}
        t.add_row(*both([str(j + 1), f"{o['start'] - t0:.1f}", f"{o['end'] - t0:.1f}", str(o["n_ref"]),
                         fmt(o["max_h_m"]), fmt(o["max_v_m"])],
                        [fmt(s_o.get("max_h_m")), fmt(s_o.get("max_v_m"))]))
    for stat in ("mean", "worst", "rms"):
        t.add_row(*both([stat, "", "", "", fmt(sc["horizontal_m"][stat]), fmt(sc["vertical_m"][stat])],
                        [fmt(sm["horizontal_m"][stat]), fmt(sm["vertical_m"][stat])] if sm else []))
    t.add_row(*both(["outside RMS", "", "", str(sc["outside"]["n"]), fmt(sc["outside"]["rms_h_m"], 3),
                     fmt(sc["outside"]["rms_v_m"], 3)],
                    [fmt(sm["outside"]["rms_h_m"], 3), fmt(sm["outside"]["rms_v_m"], 3)] if sm else []))
    return t


TERMINAL_WIDTH = 100  # the terminal tables fit it; a log file is written at it (rich would take 80)


def _console(file=None):
    """A rich console at the terminal's width, or TERMINAL_WIDTH for a file or a pipe."""
    from rich.console import Console

    to_terminal = file is None and sys.stdout.isatty()
    return Console(file=file, width=None if to_terminal else TERMINAL_WIDTH)


def print_outage_table(summary: dict, file=None) -> None:
    _console(file).print(outage_table(summary))


def print_comparison(paths: list[str | Path], file=None) -> None:
    """The totals and the per-segment tables on the terminal (or `file`)."""
    console = _console(file)
    for table in comparison_tables(load_all(paths)):
        console.print(table)


def comparison_table(paths: list[str | Path]) -> str:
    """The same tables as plain text."""
    buf = io.StringIO()
    print_comparison(paths, buf)
    return buf.getvalue()
