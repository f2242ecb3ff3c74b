"""The report as a reader uses it: every panel shows what its legend names, the
tight filter's pseudorange updates are drawn normalised against their gate, and
the page's numbers equal a recomputation from the results tables and truth.npz that
shares no code with the report."""

import base64
import re

import numpy as np
import pytest
from scipy.stats import chi2

from figcheck import check_figure, mode_points
from gpsins import replay, report, sim
from gpsins import results as results_mod
from gpsins.sim.messages import MEASUREMENT_DELAY_S
from gpsins.sim.scenario import parse
from gpsins.sim.session import write_session

START = {"gps_week": 1590, "gps_tow_s": 419400.0, "lat_deg": 59.37, "lon_deg": 17.95, "height_m": 30.0,
         "heading_deg": 160.0}
DRIVE = [{"label": "Start-A", "duration_s": 8, "speed_mps": 0},
         {"label": "A-B", "duration_s": 6, "speed_mps": 8},
         {"label": "B-C", "duration_s": 10, "turn_deg": 70},
         {"label": "C-Stop", "duration_s": 10, "speed_mps": 11}]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("report")
    s = sim.simulate(parse({"name": "short", "start": START, "segment": DRIVE}), seed=11)
    session = write_session(s, root / "session")
    outs = [replay.replay(session, root / mode, mode=mode, gps_latency_s=MEASUREMENT_DELAY_S).out
            for mode in ("loose", "tight")]
    page = report.make_report(outs, root / "report")
    return root, session, outs, page


@pytest.fixture(scope="module")
def figs(runs):
    import matplotlib.pyplot as plt

    built = report.build_figures(runs[2])
    yield built
    for f in built.values():
        plt.close(f)


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
        for (panel, mode), n in check_figure(name, fig).items():
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
    base_t0 = results_mod.load(runs[2][0])["t"][0]
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


def test_2d_and_3d_fix_nis_have_their_own_bands(figs):
    axs = figs["consistency.png"].axes
    for ax, dof in ((axs[0], 3), (axs[1], 2)):
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


def test_the_terminal_shows_the_per_segment_table(runs):
    out = report.comparison_table(runs[2])  # what `gpsins report` and `gpsins run` print (rich)
    assert "Errors per segment" in out and "B-C" in out and "receiver H" in out and "tight V" in out
