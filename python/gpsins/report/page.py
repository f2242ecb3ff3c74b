"""The report's page: its tables and text, written as Markdown and as HTML with the figures
(``make_report``).
"""

from __future__ import annotations

import base64
import html
from pathlib import Path


from ..nav import noise_from_data
from .figures import figures
from .data import (Result, load_all, stats, innovation_intervals, receiver_errors, receiver_segment_table,
                   segment_table, shows_outage_table, time_origin, time_origin_text)


def fmt(x, d=2):
    return "-" if x is None else f"{x:.{d}f}"


def page_tables(results: list[Result]) -> list[tuple[str, list[str], list[list[str]]]]:
    """The page's tables as (title, header, rows) of text, shared by the Markdown and HTML pages."""
    tables = []
    segs = [(r.name, segment_table(r)) for r in results]
    rec = receiver_segment_table(results[0])
    if any(t for _, t in segs):
        head = ["segment", "sats"] + [f"{n} {c} rms / max (m)" for n, _ in segs for c in ("H", "V")]
        if rec:
            head += ["receiver H rms / max (m)", "receiver V rms / max (m)"]
        head += [f"{n} NEES" for n, _ in segs]
        rows = []
        for i, row in enumerate(segs[0][1]):
            cells = [row["segment"], f"{row['sats_min']}-{row['sats_max']}"]
            for _, tab in segs + ([("receiver", rec)] if rec else []):
                rr = tab[i]
                cells += [f"{fmt(rr.get('h_rms'))} / {fmt(rr.get('h_max'))}",
                          f"{fmt(rr.get('v_rms'))} / {fmt(rr.get('v_max'))}"]
            cells += [fmt(tab[i].get("nees9_mean")) for _, tab in segs]
            rows.append(cells)
        tables.append(("Errors per segment (Table 6.1)", head, rows))
    t0 = time_origin(results[0])
    iv = [x for r in results for x in innovation_intervals(r)]
    head = ["mode", "update", "PRN", "from (s)", "to (s)", "updates", "max |innovation| / sigma", "rejected"]
    rows = [[x["mode"], x["kind"], "-" if x["prn"] is None else str(x["prn"]), f"{x['t_start'] - t0:.1f}",
             f"{x['t_end'] - t0:.1f}", str(x["updates"]), f"{x['max_ratio']:.1f}", str(x["rejected"])] for x in iv]
    tables.append(("Intervals with innovations outside 3 sigma (Table 7.4)", head, rows))
    groups: dict = {}  # runs with the same outages share a table (an ins run's free stretch is its own)
    for r in results:
        if shows_outage_table(r.run):
            key = tuple((o["start"], o["end"]) for o in r.run["scoring"]["per_outage"])
            groups.setdefault(key, []).append(r)
    tables += [outage_page_table(g, t0) for g in groups.values()]
    return tables


def outage_page_table(scored: list[Result], t0: float):
    """Per outage the maximum horizontal and vertical drift of each run (runs with the same outages), then
    mean, worst and RMS of the per-outage maxima and the RMS outside outages: (title, header, rows); times
    from t0, the report's origin."""
    head = ["outage", "from (s)", "to (s)", "ref epochs"] + [f"{r.name} {c} (m)" for r in scored for c in ("H", "V")]
    rows = []
    first = scored[0].run["scoring"]["per_outage"]
    for j, o in enumerate(first):
        cells = [str(j + 1), f"{o['start'] - t0:.1f}", f"{o['end'] - t0:.1f}", str(o["n_ref"])]
        for r in scored:
            po = r.run["scoring"]["per_outage"]
            oo = po[j] if j < len(po) else {}
            cells += [fmt(oo.get("max_h_m")), fmt(oo.get("max_v_m"))]
        rows.append(cells)
    for stat in ("mean", "worst", "rms"):
        rows.append([stat, "", "", ""] + [fmt(r.run["scoring"][f"{c}_m"][stat])
                                          for r in scored for c in ("horizontal", "vertical")])
    rows.append(["outside RMS", "", "", str(scored[0].run["scoring"]["outside"]["n"])] +
                [fmt(r.run["scoring"]["outside"][f"rms_{c}_m"], 3) for r in scored for c in ("h", "v")])
    ref = scored[0].run["scoring"]
    what = "free navigation (--mode ins)" if "ins_free_from" in ref else "per outage"
    return (f"Drift {what} against {Path(ref['reference']).name} ({ref['point']} point)", head, rows)


def _run_lines(r: Result) -> list[str]:
    run = r.run
    al = run.get("alignment") or {}
    lines = [f"{run.get('kind', 'session')}: {Path(run['session']).name}; IMU samples {run['imu_samples']}; "
             f"filter wall time {run['wall_time_s']['filter_s']:.2f} s (replay {run['wall_time_s']['total_s']:.2f} s)"]
    if al:
        lines.append(f"alignment: {al['method']}, IMU clock {al['imu_clock_ppm']:+.1f} ppm, "
                     f"{al['imu_frames_missing']} frames missing, clock steps {al['clock_steps_s']}")
    p = run.get("provenance")
    if p:
        sim = p.get("simulation") or {}
        lines.append(f"made by gpsins {p['gpsins']}" + (f": `{p['command']}`" if p.get("command") else "") +
                     f"; configuration sha256 {p['config_sha256'][:16]}" +
                     (f"; scenario {sim['scenario']}, seed {sim['seed']}" if sim.get("scenario") else ""))
    lines += ["counters: " + ", ".join(f"{k} {v}" for k, v in run["counters"].items() if v),
              "skipped: " + (", ".join(f"{k}: {v}" for k, v in run["skipped"].items()) or "nothing")]
    e = run.get("errors") or {}
    if e:
        inside = e.get("inside_3_sigma")
        lines.append(f"errors vs truth: horizontal RMS {fmt(e.get('horizontal_rms_m'))} m "
                     f"(max {fmt(e.get('horizontal_max_m'))}), vertical RMS {fmt(e.get('vertical_rms_m'))} m "
                     f"(max {fmt(e.get('vertical_max_m'))}), mean NEES {fmt(e.get('nees9_mean'))} (9 dof), "
                     f"inside 3 sigma {fmt(None if inside is None else 100 * inside, 1)} %")
    sc = run.get("scoring") or {}
    if shows_outage_table(run):
        lines.append(f"against {Path(sc['reference']).name} ({sc['point']} point): RMS of the per-outage maximum "
                     f"horizontal drift {sc['horizontal_m']['rms']:.2f} m over {sc['n_scored']} outages; outside "
                     f"outages RMS {sc['outside']['rms_h_m']:.3f} m horizontal, {sc['outside']['rms_v_m']:.3f} m "
                     "vertical")
    return lines


def _warning_lines(results: list[Result]) -> list[str]:
    """What went wrong in any run (replay's health lines: divergence, resets, sources often refused)."""
    return [f"{r.name}: {w}" for r in results for w in r.run.get("health", [])]


def _receiver_line(r: Result) -> str | None:
    _, e = receiver_errors(r)
    s = stats(e)
    if not s:
        return None
    return (f"receiver's own fixes vs truth: horizontal RMS {s['h_rms']:.2f} m (max {s['h_max']:.2f}), "
            f"vertical RMS {s['v_rms']:.2f} m (max {s['v_max']:.2f}) over {len(e)} fixes")


def _times_line(results: list[Result]) -> str:
    return f"Times in the tables and figures: {time_origin_text(results[0])}."


def _captions(results: list[Result], figs: list[str]) -> list[tuple[str, str, str]]:
    """(file, short name, caption) per figure."""
    from . import figures as report_figures

    caps = report_figures.figure_captions(results)
    return [(f, f.removesuffix(".png").replace("_", " "), caps.get(f, "")) for f in figs]


def summary_markdown(results: list[Result], figs: list[str]) -> str:
    results = load_all(results)
    lines = ["# gpsins replay report", ""]
    lines += [f"**WARNING: {w}**" for w in _warning_lines(results)] + ([""] if _warning_lines(results) else [])
    for r in results:
        lines += [f"## {r.name}", ""] + [f"- {x}" for x in _run_lines(r) + noise_from_data.summary_lines(r.run)] + [""]
    rec = _receiver_line(results[0])
    if rec:
        lines += [f"- {rec}", ""]
    lines += [_times_line(results), ""]
    for title, head, rows in page_tables(results):
        lines += [f"## {title}", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        lines += ["| " + " | ".join(c) + " |" for c in rows] or ["| none |" + " |" * (len(head) - 1)]
        lines.append("")
    lines += ["## Figures", ""]
    for k, (f, name, cap) in enumerate(_captions(results, figs), 1):
        lines += [f"![{name}]({f})", "", f"*Figure {k} ({name}).* {cap}", ""]
    return "\n".join(lines)


def summary_html(results: list[Result], figs: list[str], fig_dir: Path) -> str:
    """One self-contained page: the same text and tables, every figure embedded as base64 PNG."""
    results = load_all(results)
    esc = html.escape
    parts = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8"><title>gpsins replay report</title>',
             "<style>body{font-family:sans-serif;max-width:1200px;margin:auto;padding:1em}"
             "table{border-collapse:collapse;font-size:90%}td,th{border:1px solid #bbb;padding:2px 6px;"
             "text-align:right}td:first-child{text-align:left}img{max-width:100%}</style></head><body>",
             "<h1>gpsins replay report</h1>"]
    parts += [f'<p style="color:#b00"><b>WARNING: {esc(w)}</b></p>' for w in _warning_lines(results)]
    for r in results:
        parts.append(f"<h2>{esc(r.name)}</h2><ul>"
                     + "".join(f"<li>{esc(x)}</li>" for x in _run_lines(r) + noise_from_data.summary_lines(r.run))
                     + "</ul>")
    rec = _receiver_line(results[0])
    if rec:
        parts.append(f"<ul><li>{esc(rec)}</li></ul>")
    parts.append(f"<p>{esc(_times_line(results))}</p>")
    for title, head, rows in page_tables(results):
        parts.append(f"<h2>{esc(title)}</h2><table><tr>" + "".join(f"<th>{esc(h)}</th>" for h in head) + "</tr>")
        parts += ["<tr>" + "".join(f"<td>{esc(c)}</td>" for c in row) + "</tr>" for row in rows]
        parts.append("</table>" + ("" if rows else "<p>none</p>"))
    parts.append("<h2>Figures</h2>")
    for k, (f, name, cap) in enumerate(_captions(results, figs), 1):
        data = base64.b64encode((fig_dir / f).read_bytes()).decode("ascii")
        parts.append(f'<figure><img alt="{esc(name)}" src="data:image/png;base64,{data}"><figcaption>'
                     f"<b>Figure {k} ({esc(name)}).</b> {esc(cap)}</figcaption></figure>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def make_report(paths: list[str | Path], out: str | Path) -> Path:
    """Figures, report.md and the self-contained report.html in `out`; returns the Markdown page."""
    results = load_all(paths)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    figs = figures(results, out)
    page = out / "report.md"
    page.write_text(summary_markdown(results, figs), encoding="utf-8")
    (out / "report.html").write_text(summary_html(results, figs, out), encoding="utf-8")
    return page
