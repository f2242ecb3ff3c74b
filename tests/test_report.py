"""The report as a reader uses it: every panel shows what its legend names, the
tight filter's pseudorange updates are drawn normalised against their gate, and
the page's numbers equal a recomputation from the results tables and truth.npz that
shares no code with the report; what an axis leaves out is marked, legends look like
what they name, every figure is captioned, and figures and tables share one time origin."""

import base64
import contextlib
import dataclasses
import io
import json
import re
from pathlib import Path

import numpy as np
import pytest
from matplotlib.collections import PolyCollection
from matplotlib.colors import to_rgba
from scipy.stats import chi2

from figcheck import check_figure, mode_points
from gpsins.replay import run
from gpsins.report import data as report_data
from gpsins import sim
from gpsins.report import page as report_page
from gpsins.report import terminal as report_terminal
from gpsins.report import figures as report_figures_mod
from gpsins.report import draw
from gpsins.replay import results as results_mod
from gpsins.sim.messages import MEASUREMENT_DELAY_S
from gpsins.sim.scenario import parse
from gpsins.sim.session import write_session

START = {"gps_week": 1590, "gps_tow_s": 419400.0, "lat_deg": 59.37, "lon_deg": 17.95, "height_m": 30.0,
         "heading_deg": 160.0}
DRIVE = [{"label": "Start-A", "duration_s": 8, "speed_mps": 0},
         {"label": "A-B", "duration_s": 6, "speed_mps": 8},
         {"label": "B-C", "duration_s": 10, "turn_deg": 70},
         {"label": "C-Stop", "duration_s": 10, "speed_mps": 11}]
WALK = Path(__file__).parent / "data" / "walk_0827" / "walk_0827_ubx.toml"


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("report")
    s = sim.simulate(parse({"name": "short", "start": START, "segment": DRIVE}), seed=11)
    session = write_session(s, root / "session")
    outs = [run.replay(session, root / mode, mode=mode, gps_latency_s=MEASUREMENT_DELAY_S).out
            for mode in ("loose", "tight")]
    page = report_page.make_report(outs, root / "report")
    return root, session, outs, page


def _closing(built):
    import matplotlib.pyplot as plt

    try:
        yield built
    finally:
        for f in built.values():
            plt.close(f)


def _many_figures():
    import matplotlib

    return matplotlib.rc_context({"figure.max_open_warning": 0})  # several sets are open at once here


def _build(results):
    with _many_figures():
        return report_figures_mod.build_figures(results)


@contextlib.contextmanager
def _built(results):
    yield from _closing(_build(results))


@pytest.fixture(scope="module")
def figs(runs):
    yield from _closing(_build(runs[2]))


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    """A data set (no truth, no segments, no 2D fixes, outages scored against its RTK reference), its
    replay smoothed as well: results directory and report page."""
    root = tmp_path_factory.mktemp("walk")
    out = run.replay(WALK, root / "loose", mode="loose", smooth=True).out
    with _many_figures():
        return out, report_page.make_report([out], root / "report")


@pytest.fixture(scope="module")
def walk_figs(walk):
    yield from _closing(_build([walk[0]]))


def _variant(r, **arrays):
    """A copy of a loaded result with some of its arrays replaced."""
    return dataclasses.replace(r, a={**r.a, **arrays})


def _with_2d_fixes(r):
    """The run with its later half of 3D fix updates made 2D fixes (north, east rows; no vertical)."""
    kind = r.a["upd_kind"].copy()
    fix = np.flatnonzero(kind == 1)
    kind[fix[len(fix) // 2:]] = 2
    nu, sig, dof = r.a["upd_innovation"].copy(), r.a["upd_innovation_sigma"].copy(), r.a["upd_dof"].copy()
    nu[kind == 2, 2] = sig[kind == 2, 2] = np.nan
    dof[kind == 2] = 2
    return _variant(r, upd_kind=kind, upd_innovation=nu, upd_innovation_sigma=sig, upd_dof=dof)


def _origin(out) -> float:
    """The first GNSS epoch as replay recorded it (the --outages origin)."""
    return json.loads((Path(out) / "run.json").read_text())["outages"]["gnss_first_t"]


def _edge_marks(ax) -> list:
    return [ln for ln in ax.get_lines() if ln.get_gid() == draw.EDGE_GID]


def _has_data(ax) -> bool:
    """Something drawn from data: a line or markers with more than the two points of a reference line,
    or a collection (bands, scatter)."""
    lines = [ln for ln in ax.get_lines() if np.isfinite(np.asarray(ln.get_ydata(), float)).sum() > 2]
    return bool(lines) or any(len(c.get_paths()) for c in ax.collections)


def test_the_report_has_every_figure(figs, runs):
    expected = {"trajectory.png", "position_error.png", "attitude.png", "sigma.png", "biases.png", "bias_sigma.png",
                "innovations.png", "pseudorange.png", "gnss.png", "consistency.png", "clock.png", "visibility.png",
                "skyplot.png"}
    assert set(figs) == expected
    assert {p.name for p in (runs[0] / "report").glob("*.png")} == expected
    assert figs["gnss.png"].axes[0].get_title()


def test_every_panel_shows_each_mode_its_legend_names(figs):
    seen = {}
    for name, fig in figs.items():
        for (_panel, mode), _n in check_figure(name, fig).items():
            seen.setdefault(name, set()).add(mode)
    # Both filters appear where both apply; the tight filter's own figures name it alone.
    for name in ("trajectory.png", "position_error.png", "attitude.png", "sigma.png", "biases.png", "bias_sigma.png"):
        assert seen[name] == {"loose", "tight"}, (name, seen.get(name))
    assert seen["pseudorange.png"] == {"tight"} and seen["clock.png"] == {"tight"}
    assert "loose" in seen["innovations.png"] and "tight" in seen["gnss.png"]


def test_legends_say_which_line_style_is_which_axis(figs):
    texts = {t.get_text() for t in figs["sigma.png"].axes[0].get_legend().get_texts()}
    assert {"loose", "tight", "north", "east", "down"} <= texts
    biases = figs["biases.png"].axes
    assert any("truth" in t.get_text() for t in biases[0].get_legend().get_texts())
    for ax in biases:  # the true residual bias is drawn in every panel
        assert any(line.get_linestyle() == "--" and len(line.get_xdata()) > 100 for line in ax.get_lines())


def test_pseudorange_innovations_are_normalised_per_satellite_with_the_gate(figs, runs):
    z = results_mod.load(runs[2][1])
    k = z["upd_kind"] == 6
    t0 = z["t"][0]  # the tight result is not the first: its own start differs
    ax = figs["pseudorange.png"].axes[0]
    base_t0 = _origin(runs[2][0])  # the report's time origin: the first GNSS epoch
    prns = np.unique(z["upd_id"][k])
    assert len(prns) >= 4
    for line in ax.get_lines():
        label = line.get_label()
        if label.startswith("PRN "):
            m = k & (z["upd_id"] == int(label[4:])) & (z["upd_accepted"] > 0)
            expect = z["upd_innovation"][m, 0] / z["upd_innovation_sigma"][m, 0]
            assert np.allclose(line.get_ydata(), expect)
            assert np.allclose(line.get_xdata(), z["upd_t"][m] - base_t0)
    gate = np.sqrt(chi2.ppf(0.9999, 1))  # the preset's gate_probability, one degree of freedom
    levels = {round(abs(line.get_ydata()[0]), 3) for line in ax.get_lines() if len(set(line.get_ydata())) == 1}
    assert round(gate, 3) in levels and 3.0 in levels
    assert t0 >= base_t0


def test_2d_and_3d_fix_nis_have_their_own_bands(runs):
    loose, tight = (report_data.load(p) for p in runs[2])
    with _built([_with_2d_fixes(loose), tight]) as built:
        axs = {ax.get_ylabel(): ax for ax in built["consistency.png"].axes}
    for ax, dof in ((axs["NIS, 3D fixes"], 3), (axs["NIS, 2D fixes"], 2)):
        lo, hi = chi2.ppf([0.025, 0.975], dof)
        ys = [[p.get_y(), p.get_y() + p.get_height()] if hasattr(p, "get_height")
              else sorted({v[1] for v in p.get_xy()}) for p in ax.patches]
        assert any(np.allclose([y[0], y[-1]], [lo, hi]) for y in ys), (dof, ys)


def test_high_dop_does_not_set_the_scale(figs, runs):
    ax = figs["innovations.png"].axes[0]
    z = results_mod.load(runs[2][0])
    fix = np.isin(z["upd_kind"], (1, 2))
    typical = 3 * np.median(z["upd_innovation_sigma"][fix, 0])
    assert ax.get_ylim()[1] < 10 * typical
    assert mode_points(ax, "loose") >= fix.sum()


def _tables(page: str) -> dict[str, list[list[str]]]:
    out = {}
    for title, body in re.findall(r"<h2>([^<]*)</h2><table>(.*?)</table>", page, re.S):
        out[title] = [re.findall(r"<t[dh]>(.*?)</t[dh]>", row) for row in re.findall(r"<tr>(.*?)</tr>", body)]
    return out


def _ned(lat, lon):
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    return (np.stack([-sl * co, -sl * so, cl], -1), np.stack([-so, co, np.zeros_like(lat)], -1),
            np.stack([cl * co, cl * so, sl], -1))


def _errors(t, r, truth):
    """Horizontal and vertical errors of positions r at times t against truth.npz, by direct interpolation."""
    tt = truth["tow_s"]
    ref = np.column_stack([np.interp(t, tt, truth["r_ecef"][:, i]) for i in range(3)])
    n, e, u = _ned(np.interp(t, tt, truth["lat"]), np.interp(t, tt, truth["lon"]))
    d = r - ref
    return np.hypot(np.sum(d * n, 1), np.sum(d * e, 1)), np.sum(d * u, 1)


def _rms_max(h, v):
    return (np.sqrt(np.mean(h ** 2)), h.max(), np.sqrt(np.mean(v ** 2)), np.abs(v).max())


def _cell(text):
    return [float(x) for x in text.split(" / ")]


def test_the_page_numbers_equal_an_independent_recomputation(runs):
    root, session, outs, page = runs
    html_page = (root / "report" / "report.html").read_text()
    tables = _tables(html_page)
    seg = tables["Errors per segment (Table 6.1)"]
    head, rows = seg[0], seg[1:]
    truth = dict(np.load(session / "truth.npz"))
    assert int(truth["gps_week"]) == START["gps_week"]
    bounds = truth["segment_t"] + float(truth["t0_tow_s"])
    assert [r[0] for r in rows] == [str(x) for x in truth["segment_labels"]]
    for mode_col, out in zip((2, 4), outs):
        z = results_mod.load(out)
        inside = (z["t"] >= truth["tow_s"][0]) & (z["t"] <= truth["tow_s"][-1]) & z["heading_known"]
        h, v = _errors(z["t"], z["r_ecef"], truth)
        checked = 0
        for row, (a, b) in zip(rows, bounds):
            m = inside & (z["t"] >= a) & (z["t"] < b)
            if not m.any():
                assert row[mode_col] == "- / -"
                continue
            hr, hm, vr, vm = _rms_max(h[m], v[m])
            assert np.allclose(_cell(row[mode_col]), [hr, hm], atol=0.006), (head[mode_col], row)
            assert np.allclose(_cell(row[mode_col + 1]), [vr, vm], atol=0.006), (head[mode_col + 1], row)
            # The segment's mean NEES (a lap's consistency), from the run's per-epoch NEES.
            nees_col = head.index(f"{head[mode_col].split(' ')[0]} NEES")
            assert float(row[nees_col]) == pytest.approx(np.nanmean(z["nees9"][m]), abs=0.006, rel=0.001)
            checked += 1
        assert checked >= 3
    # The receiver's own fixes (valid ones, inside the truth's span).
    assert head[6].startswith("receiver H")
    z = results_mod.load(outs[0])
    f = z["fixes"][z["fixes"][:, 9] > 0]
    ok_t = z["t"][np.isfinite(z["err_ned_m"][:, 0])]
    f = f[(f[:, 0] >= ok_t[0]) & (f[:, 0] <= ok_t[-1])]
    h, v = _errors(f[:, 0], f[:, 1:4], truth)
    for row, (a, b) in zip(rows, bounds):
        m = (f[:, 0] >= a) & (f[:, 0] < b)
        if m.any():
            hr, hm, vr, vm = _rms_max(h[m], v[m])
            assert np.allclose(_cell(row[6]), [hr, hm], atol=0.006) and np.allclose(_cell(row[7]), [vr, vm], atol=0.006)
    # The overall line per mode.
    z = results_mod.load(outs[0])
    hk = z["heading_known"] & (z["t"] >= truth["tow_s"][0]) & (z["t"] <= truth["tow_s"][-1])
    h, v = _errors(z["t"][hk], z["r_ecef"][hk], truth)
    m = re.search(r"<h2>loose</h2><ul>.*?horizontal RMS ([0-9.]+) m \(max ([0-9.]+)\), vertical RMS ([0-9.]+) m",
                  html_page, re.S)
    assert np.allclose([float(x) for x in m.groups()], [np.sqrt(np.mean(h ** 2)), h.max(), np.sqrt(np.mean(v ** 2))],
                       atol=0.006)


def test_intervals_outside_3_sigma_cover_every_such_update(runs):
    root, _, outs, _ = runs
    tables = _tables((root / "report" / "report.html").read_text())
    rows = tables["Intervals with innovations outside 3 sigma (Table 7.4)"][1:]
    for mode, out in zip(("loose", "tight"), outs):
        z = results_mod.load(out)
        sel = np.isin(z["upd_kind"], (1, 2, 6))
        with np.errstate(invalid="ignore"):
            ratio = np.abs(z["upd_innovation"][sel]) / z["upd_innovation_sigma"][sel]
        beyond = int(np.sum(np.nanmax(np.where(np.isfinite(ratio), ratio, 0), axis=1) > 3))
        assert sum(int(r[5]) for r in rows if r[0] == mode) == beyond


def test_the_html_page_is_self_contained(runs):
    root = runs[0]
    page = (root / "report" / "report.html").read_text()
    sources = re.findall(r'src="([^"]*)"', page)
    assert len(sources) == len(list((root / "report").glob("*.png")))
    for src in sources:
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"
    assert "href=" not in page


def test_the_terminal_shows_the_per_segment_tables_within_100_columns(runs, walk):
    out = report_terminal.comparison_table(runs[2])  # what `gpsins report` and `gpsins run` print (rich)
    assert "loose: errors per segment" in out and "tight: errors per segment" in out and "B-C" in out
    assert "receiver fixes: errors per segment" in out and "V RMS (max), m" in out
    summary = json.loads((walk[0] / "run.json").read_text())
    buf = io.StringIO()
    report_terminal.print_outage_table(summary, buf)  # what `gpsins replay` prints, the smoothed drift beside
    assert "smooth H" in buf.getvalue()
    for text in (out, buf.getvalue()):  # nothing cut on an 80-100 column terminal or in a log file
        assert max(len(line) for line in text.splitlines()) <= 100 and "\u2026" not in text


# ---------------------------------------------------------------- issue 41: figures a reader can trust


def test_values_beyond_an_axis_are_marked_at_its_edge(runs):
    loose, tight = (report_data.load(p) for p in runs[2])
    e = loose.a["err_ned_m"].copy()
    spike = slice(len(e) // 2, len(e) // 2 + 20)
    e[spike, 1] = 80.0  # east, far beyond the bulk
    with _built([_variant(loose, err_ned_m=e), tight]) as built:
        ax = built["position_error.png"].axes[0]
    assert ax.get_ylim()[1] < 80.0
    t = loose.a["t"][spike] - _origin(runs[2][0])
    marks = [ln for ln in _edge_marks(ax) if to_rgba(ln.get_color()) == to_rgba("tab:blue")]
    x = np.concatenate([ln.get_xdata() for ln in marks]) if marks else np.zeros(0)
    assert np.sum((x >= t[0]) & (x <= t[-1])) == 1  # one mark for the stretch, at the top edge
    assert all(np.allclose(ln.get_ydata(), 0.975) for ln in marks if ln.get_marker() == "^")
    assert any("beyond the axis" in tx.get_text() for tx in ax.get_legend().get_texts())


def test_every_band_has_a_legend_swatch_that_looks_like_it(figs):
    for name, fig in figs.items():
        swatches = [to_rgba(p.get_facecolor()) for ax in fig.axes if ax.get_legend()
                    for p in ax.get_legend().get_patches()]
        for ax in fig.axes:
            for band in (c for c in ax.collections if isinstance(c, PolyCollection)):
                colour = tuple(band.get_facecolor()[0])
                assert any(np.allclose(colour, sw) for sw in swatches), (name, ax.get_ylabel(), colour, swatches)


def test_one_tiny_nis_does_not_squash_the_consistency_plot(runs):
    loose, tight = (report_data.load(p) for p in runs[2])
    nis = loose.a["upd_nis"].copy()
    j = np.flatnonzero(loose.a["upd_kind"] == 1)[5]
    nis[j] = 1e-21
    with _built([_variant(loose, upd_nis=nis), tight]) as built:
        ax = next(a for a in built["consistency.png"].axes if a.get_ylabel() == "NIS, 3D fixes")
    fix = np.delete(nis[loose.a["upd_kind"] == 1], 5)
    assert ax.get_ylim()[0] > fix.min() / 10  # the bulk sets the range, not the one near zero
    marks = [ln for ln in _edge_marks(ax) if ln.get_marker() == "v"]
    assert any(np.isclose(x, loose.a["upd_t"][j] - _origin(runs[2][0])) for ln in marks for x in ln.get_xdata())


def test_the_tight_filters_low_pseudorange_nis_is_explained(figs, runs):
    z = results_mod.load(runs[2][1])
    k = z["upd_kind"] == 6
    median = np.median(z["upd_nis"][k])
    assert median < chi2.ppf(0.25, 1)  # low, by the preset's design
    legend = [t.get_text() for t in figs["pseudorange.png"].axes[1].get_legend().get_texts()]
    assert any(t.startswith("tight pseudorange NIS") and "by design" in t for t in legend), legend
    # The caption says why: the correlated error's variance inflated by (1 + a) / (1 - a) per update.
    dt = np.median(np.concatenate([np.diff(z["upd_t"][k & (z["upd_id"] == p)]) for p in np.unique(z["upd_id"][k])]))
    a = np.exp(-dt / 20.0)  # the preset's pseudorange_error_gm_tau_s
    caption = _captions(runs[3])["pseudorange.png"]
    assert "by design" in caption and f"= {(1 + a) / (1 - a):.0f} " in caption and f"median {median:.2g}" in caption


def test_2d_fixes_are_drawn_in_north_and_east_with_their_3_sigma(runs):
    loose, tight = (report_data.load(p) for p in runs[2])
    two_d = _with_2d_fixes(loose)
    with _built([two_d, tight]) as built:
        axs = built["innovations.png"].axes
    k = two_d.a["upd_kind"] == 2
    t = two_d.a["upd_t"][k] - _origin(runs[2][0])
    for i, axis in enumerate(("north", "east")):
        ax = next(a for a in axs if a.get_ylabel() == f"2D fix {axis} (m)")
        points = [ln for ln in ax.get_lines() if ln.get_marker() == "s" and ln.get_gid() is None]
        assert len(points) == 1
        np.testing.assert_allclose(points[0].get_ydata(), two_d.a["upd_innovation"][k, i])
        # Each update's +-3 sigma is drawn at its time (a line, or a tick where it has no neighbour).
        bounds = [ln for ln in ax.get_lines() if ln.get_marker() in ("None", "_")]
        drawn = {(round(x, 6), round(y, 6)) for ln in bounds for x, y in zip(ln.get_xdata(), ln.get_ydata())
                 if np.isfinite(y)}
        s3 = 3 * two_d.a["upd_innovation_sigma"][k, i]
        assert all((round(x, 6), round(sgn * y, 6)) in drawn for x, y in zip(t, s3) for sgn in (1, -1))
    for ax in axs:
        if ax.get_ylabel().startswith("3D fix"):
            assert not any(ln.get_marker() == "s" for ln in ax.get_lines())  # no 2D fix on an ECEF axis


def test_yaw_is_not_drawn_across_its_wrap(walk_figs):
    ax = walk_figs["attitude.png"].axes[0]
    lines = [ln for ln in ax.get_lines() if ln.get_label() in ("loose", "loose smoothed")]
    assert len(lines) == 2
    for ln in lines:
        y = np.asarray(ln.get_ydata(), float)
        assert np.nanmax(y) > 170 and np.nanmin(y) < -170  # the walk turns through south
        steps = np.abs(np.diff(y))
        assert np.nanmax(steps) < 180.0


def test_the_trajectory_title_mentions_segments_only_when_there_are_some(figs, walk_figs):
    assert "segment" in figs["trajectory.png"].axes[0].get_title()
    assert "segment" not in walk_figs["trajectory.png"].axes[0].get_title()


def test_no_panel_is_left_empty(figs, walk_figs):
    for built in (figs, walk_figs):
        for name, fig in built.items():
            for ax in fig.axes:
                if ax.get_label() != "<colorbar>":
                    assert _has_data(ax), (name, ax.get_ylabel())
    assert not any("2D" in ax.get_ylabel() for ax in walk_figs["consistency.png"].axes)


def test_the_smoothed_run_draws_and_counts_no_innovations(walk, walk_figs):
    names = {r.name for r in report_data.load_all([walk[0]])}
    assert names == {"loose", "loose smoothed"}
    for name in ("innovations.png", "consistency.png"):
        for ax in walk_figs[name].axes:
            assert mode_points(ax, "loose") > 0
            labels = [t.get_text() for t in ax.get_legend().get_texts()] if ax.get_legend() else []
            assert not any("smoothed" in t for t in labels), (name, labels)
            assert not any(to_rgba(ln.get_color()) == to_rgba("tab:cyan") for ln in ax.get_lines())
    rows = _tables(walk[1].with_suffix(".html").read_text())["Intervals with innovations outside 3 sigma (Table 7.4)"]
    assert not any(r[0] == "loose smoothed" for r in rows[1:])
    # It is still drawn where it has its own arrays.
    assert "loose smoothed" in {t.get_text() for t in walk_figs["attitude.png"].axes[0].get_legend().get_texts()}


def _captions(page: Path) -> dict[str, str]:
    """Each figure's caption on the Markdown page, by file name."""
    return dict(re.findall(r"^!\[[^]]*\]\(([^)]+)\)\n\n(.+)$", page.read_text(), re.M))


def test_every_figure_has_a_caption_saying_what_it_shows(runs, walk):
    for page in (runs[3], walk[1]):
        figures = sorted(p.name for p in page.parent.glob("*.png"))
        caps = _captions(page)
        assert sorted(caps) == figures
        html_caps = re.findall(r"<figcaption>(.*?)</figcaption>", page.with_suffix(".html").read_text(), re.S)
        assert len(html_caps) == len(figures)
        for text in list(caps.values()) + html_caps:
            assert len(text) > 120 and not re.search(r"\w+\.png", text), text
        assert len(set(caps.values())) == len(caps)
        for name, text in caps.items():
            if name not in ("trajectory.png", "skyplot.png"):
                assert "s since the first GNSS epoch" in text, name


def test_one_time_origin_for_every_time_axis_and_table(walk, walk_figs):
    out, page = walk
    first = _origin(out)
    summary = json.loads((out / "run.json").read_text())
    rows = _tables(page.with_suffix(".html").read_text())["Drift per outage against gnss_1730_sf.pos (antenna point)"]
    starts = [float(r[1]) for r in rows[1:] if r[0].isdigit()]
    assert starts == pytest.approx([o["start"] - first for o in summary["scoring"]["per_outage"]])
    assert starts == pytest.approx([25.0, 70.0])  # the data set's outages = "25:15:45:45", from the first epoch
    shaded = sorted(p.get_x() for p in walk_figs["outage_drift.png"].axes[1].patches)
    assert shaded == pytest.approx(starts)
    buf = io.StringIO()
    report_terminal.print_outage_table(summary, buf)
    assert [ln.split("│")[2].strip() for ln in buf.getvalue().splitlines() if ln.startswith(("│ 1 ", "│ 2 "))] \
        == ["25.0", "70.0"]
    for name, fig in walk_figs.items():  # every time axis says where it counts from
        labels = [ax.get_xlabel() for ax in fig.axes] + [fig.get_supxlabel()]
        times = [x for x in labels if x.startswith("time") and x != "time since the outage began (s)"]
        assert (name == "trajectory.png") != bool(times), (name, labels)
        assert all(f"s since the first GNSS epoch, GPS week 2381 tow {first % 604800:.2f} s" in x for x in times)
