"""The lab report: tables 5.1-5.10 in the report's layout (its units next to SI), the
Allan and PSD figures, as Markdown and as one HTML page with the figures embedded."""

from __future__ import annotations

import base64
import html
import io
import math
from pathlib import Path

import numpy as np

from . import noise_fit

DEG = math.degrees(1.0)
SQRT2 = math.sqrt(2.0)


def _e(x: float, sig: float | None = None, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return f"{x:.{digits}e}" + (f" ± {sig:.1e}" if sig is not None else "")


def _table(title: str, head: list[str], rows: list[list[str]]) -> list[str]:
    out = [f"**{title}**", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return out + [""]


def tables(res: dict) -> list[str]:
    md: list[str] = []
    ud, rt, dr, nz = res["updown"], res["rate_table"], res["drift"], res["noise"]
    if ud and ud["axes"]:
        rows = [[a, _e(v["bias_mps2"], v["bias_sigma_mps2"]), _e(v["scale_factor"], v["scale_factor_sigma"]),
                 f"{100 * v['scale_factor']:.3f} ± {100 * v['scale_factor_sigma']:.3f}"] for a, v in ud["axes"].items()]
        md += _table(f"Table 5.1: accelerometer bias and scale factor, up-down (eq. 5.2 corrected; g = "
                     f"{ud['gravity_mps2']:.5f} m/s^2)", ["Accelerometer", "Bias (m/s^2)", "Scale factor (unit less)",
                                                        "alpha_ii (%)"], rows)
        best = [f"{a}: {b['length_s']:.0f} s (sigma {b['scale_factor_sigma']:.1e})"
                for a, b in ((a, v.get("best_position_s")) for a, v in ud["axes"].items()) if b]
        if best:
            md += ["Position length that would minimise the scale factor's uncertainty under the drift run's noise "
                   "(white noise averages down, the bias wanders between the positions): " + "; ".join(best) + ".", ""]
    if rt:
        for a, v in rt["axes"].items():
            rows = [[f"{r['rate']:+.4f}", f"{r['mean']:+.5f}", _e(r["sigma"], digits=1)] for r in v["runs"]]
            md += _table(f"Table 5.{2 + 'xyz'.index(a)}: rotation rate test sequence, gyro {a}",
                         ["table rate rad/s", "gyro output rad/s", "output sigma rad/s"], rows)
        rows = []
        for a, v in rt["axes"].items():
            b = dr[a]["bias_rad_per_s"] if dr else v["bias_rad_per_s"]
            bs = dr[a]["bias_sigma_rad_per_s"] if dr else v["bias_sigma_rad_per_s"]
            pair = v.get("pair_eq_5_4_5_5", {})
            rows.append([a, _e(b, bs), f"{b * DEG:.4f}", _e(v["scale_factor"], v["scale_factor_sigma"]),
                         f"{100 * v['scale_factor']:.3f}", _e(v["bias_rad_per_s"], v["bias_sigma_rad_per_s"]),
                         _e(pair.get("scale_factor", float("nan"))), f"{v['chi2_per_dof']:.2f}"])
        md += _table("Table 5.5: gyro bias (drift test) and scale factor (rate table, weighted line); "
                     "line bias, widest-pair eq. 5.4 scale factor", ["Gyro", "Bias (rad/s)", "Bias (deg/s)",
                                                                     "Scale factor", "beta_ii (%)", "line bias (rad/s)",
                                                                     "eq. 5.4 pair", "chi2/dof"], rows)
    elif dr:
        rows = [[a, _e(v["bias_rad_per_s"], v["bias_sigma_rad_per_s"]), f"{v['bias_rad_per_s'] * DEG:.4f}"]
                for a, v in dr.items()]
        md += _table("Table 5.5: gyro bias from the drift test", ["Gyro", "Bias (rad/s)", "Bias (deg/s)"], rows)
    if nz:
        g = [nz.get(f"gyro_{a}") for a in "xyz"]
        ac = [nz.get(f"accel_{a}") for a in "xyz"]
        if all(g) and all(ac):
            md += _table("Table 5.6: PSD white noise, sqrt of the one-sided plateau",
                         ["Noise term", "unit", "x axis", "y axis", "z axis"],
                         [["Angular rate white noise", "(rad/s)/sqrt(Hz)"] +
                          [_e(SQRT2 * v["N_psd"], digits=2) for v in g],
                          ["Acceleration white noise", "(m/s^2)/sqrt(Hz)"] + [_e(SQRT2 * v["N_psd"], digits=2)
                                                                               for v in ac]])
            md += _table("Table 5.7: PSD white noise in the report's units (eq. 5.10, 5.11)",
                         ["Noise term", "unit", "x axis", "y axis", "z axis"],
                         [["Angular rate white noise", "deg/sqrt(h)"] +
                          [f"{v['N_psd'] * noise_fit.RAD_PER_SQRT_S_TO_DEG_PER_SQRT_H:.3f}" for v in g],
                          ["Acceleration white noise", "m/s/sqrt(h)"] + [f"{v['N_psd'] * 60:.3f}" for v in ac]])
        for kind, num, units in (("gyro", 8, ("rad", "rad/sqrt(s)", "rad/s", "rad/s/sqrt(s)")),
                                 ("accel", 9, ("m/s", "m/s/sqrt(s)", "m/s^2", "m/s^2/sqrt(s)"))):
            rows = []
            for a in "xyz":
                v = nz.get(f"{kind}_{a}")
                if not v:
                    continue
                f = v["fit"]
                cells = [a] + [(_e(f.value[t], f.sigma[t], 2) if f.value.get(t, 0) > 0 else "√ (absent)")
                               for t in ("Q", "N", "B", "K")]
                tu = noise_fit.table_units(kind, f)
                cells.append(", ".join(f"{k.split('_')[0]} {x:.3g}" for k, x in tu.items()))
                ro = f.slope_readouts
                cells.append("-" if "warning" in ro else
                             f"N {ro['N_at_tau_1']:.2e}, B {'<= ' if ro['B_is_upper_bound'] else ''}"
                             f"{ro['B_min_over_0.664']:.2e} (tau {ro['tau_at_min_s']:.0f} s; less N, K: "
                             f"{ro['B_min_less_other_terms']:.2e})")
                bump = v["bump"]
                cells.append(f"T {bump['T_s']:.0f} s, sigma {bump['sigma']:.2e}" if bump else "none")
                rows.append(cells)
            what = "gyros" if kind == "gyro" else "accelerometers"
            md += _table(f"Table 5.{num}: noise coefficients of the {what}, Allan variance ({res['estimator']}; "
                         f"fit ± 1 sigma; read-outs from taus with edf >= {res['min_edf']:g})",
                         ["", f"Q_z [{units[0]}]", f"Q [{units[1]}]", f"B [{units[2]}]", f"K [{units[3]}]",
                          "report units", "slope read-outs", "Gauss-Markov bump"], rows)
        if all(g) and all(ac):
            rows = []
            for a, vg, va in zip("xyz", g, ac):
                k = noise_fit.RAD_PER_SQRT_S_TO_DEG_PER_SQRT_H
                rows.append([a, f"{vg['N_psd'] * k:.3f}",
                             f"{vg['fit'].value['N'] * k:.3f} ± {vg['fit'].sigma['N'] * k:.3f}",
                             f"{va['N_psd'] * 60:.4f}",
                             f"{va['fit'].value['N'] * 60:.4f} ± {va['fit'].sigma['N'] * 60:.4f}"])
            md += _table("Table 5.10: PSD and Allan white-noise coefficients", ["", "Gyro PSD [deg/sqrt(h)]",
                                                                                "Gyro Allan [deg/sqrt(h)]",
                                                                                "Accl. PSD [m/s/sqrt(h)]",
                                                                                "Accl. Allan [m/s/sqrt(h)]"], rows)
    return md


def figures(res: dict) -> dict[str, bytes]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = {}
    nz = res["noise"]
    if not nz:
        return out
    for group in ("gyro", "accel"):
        cols = [n for n in nz if n.startswith(group)]
        if not cols:
            continue
        fig, axs = plt.subplots(1, 2, figsize=(12, 5))
        for n in cols:
            v = nz[n]
            r, f = v["allan"], v["fit"]
            line, = axs[0].loglog(r.tau, r.adev, "o", ms=3, label=n)
            axs[0].fill_between(r.tau, r.lo, r.hi, alpha=0.2, color=line.get_color())
            axs[0].loglog(r.tau, r.eq59_lo, "--", lw=0.7, color=line.get_color())
            axs[0].loglog(r.tau, r.eq59_hi, "--", lw=0.7, color=line.get_color())
            fitted = r.tau >= f.fitted_from_tau_s  # shorter taus: the sensor's filter, not fitted
            axs[0].loglog(r.tau[fitted], f.model_adev[fitted], "-", lw=1, color=line.get_color())
            short = r.edf < res["min_edf"]
            if short.any():
                axs[0].loglog(r.tau[short], r.adev[short], "x", color="k", ms=5)
            fr, p, fc, pc = v["psd"]
            axs[1].loglog(fc, pc, label=n, color=line.get_color())
            axs[1].axhline(2 * v["N_psd"] ** 2, ls=":", lw=0.8, color=line.get_color())
        axs[0].set_xlabel("tau (s)")
        unit = noise_fit.rate_unit(group)
        axs[0].set_ylabel(f"Allan deviation ({unit})")
        axs[0].set_title(f"{group}: {res['estimator']} ADEV, chi-square band (shaded), eq. 5.9 (dashed), fit;\n"
                         f"x: edf < {res['min_edf']:g}", fontsize=9)
        axs[0].legend(fontsize=8)
        axs[1].set_xlabel("frequency (Hz)")
        axs[1].set_ylabel(f"one-sided PSD (({unit})^2/Hz)")
        axs[1].set_title("PSD with frequency averaging; dotted: white level 2 N^2", fontsize=9)
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=100)
        plt.close(fig)
        out[f"allan_psd_{group}.png"] = buf.getvalue()
    rt = res["rate_table"]
    if rt and rt["axes"]:
        fig, ax = plt.subplots(1, len(rt["axes"]), figsize=(4 * len(rt["axes"]), 3.5), squeeze=False)
        for k, (a, v) in enumerate(rt["axes"].items()):
            x = np.array([r["rate"] for r in v["runs"]])
            y = np.array([r["mean"] for r in v["runs"]])
            line = (1 + v["scale_factor"]) * (x + v["earth_rate_along_axis_rad_per_s"]) + v["bias_rad_per_s"]
            ax[0, k].plot(x, 1e3 * (y - line), "o")
            ax[0, k].axhline(0, color="grey", lw=0.8)
            ax[0, k].set_xlabel("table rate (rad/s)")
            ax[0, k].set_ylabel("residual of the line (mrad/s)")
            ax[0, k].set_title(f"gyro {a}: s = {v['scale_factor']:.5f} ± {v['scale_factor_sigma']:.5f}", fontsize=9)
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=100)
        plt.close(fig)
        out["rate_table.png"] = buf.getvalue()
    return out


def write(res: dict, out: Path, figures: bool = True) -> None:
    figs = _figures(res) if figures else {}
    for name, data in figs.items():
        (out / name).write_bytes(data)
    head = [f"# IMU lab report ({res['plan']})", "",
            f"Site latitude {res['site']['lat_deg']:.4f} deg, height {res['site']['height_m']:.1f} m. "
            f"Allan estimator: {res['estimator']}; slope read-outs only at taus with at least "
            f"{res['min_edf']:g} equivalent degrees of freedom.", ""]
    if res["warnings"]:
        head += ["## Warnings", ""] + [f"- {w}" for w in res["warnings"]] + [""]
    body = tables(res)
    files = ["imu_preset.toml (filter configuration)", "imu.yaml (Kalibr)", "lab.json (all numbers, curves, bounds)"]
    tail = ["## Files", ""] + [f"- {f}" for f in files] + [""]
    md = head + ["## Tables", ""] + body + ["## Figures", ""] + [f"![{n}]({n})" for n in figs] + [""] + tail
    (out / "report.md").write_text("\n".join(md), encoding="utf-8")
    (out / "report.html").write_text(_html(head + ["## Tables", ""] + body + tail, figs), encoding="utf-8")


_figures = figures


def _html(md: list[str], figs: dict[str, bytes]) -> str:
    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>IMU lab report</title><style>"
             "body{font-family:sans-serif;max-width:1200px;margin:auto}table{border-collapse:collapse;margin:8px 0}"
             "td,th{border:1px solid #bbb;padding:3px 8px;font-size:13px}</style></head><body>"]
    table: list[str] = []

    def flush():
        if table:
            rows = [r.strip("|").split("|") for r in table if not set(r) <= set("|-")]
            parts.append("<table>" + "".join(
                "<tr>" + "".join(f"<{'th' if i == 0 else 'td'}>{html.escape(c.strip())}</{'th' if i == 0 else 'td'}>"
                                 for c in r) + "</tr>" for i, r in enumerate(rows)) + "</table>")
            table.clear()
    in_list = False
    for line in md:
        if line.startswith("|"):
            table.append(line)
            continue
        flush()
        if in_list and not line.startswith("- "):
            parts.append("</ul>")
            in_list = False
        if line.startswith("- ") and not in_list:
            parts.append("<ul>")
            in_list = True
        if line.startswith("# "):
            parts.append(f"<h1>{html.escape(line[2:])}</h1>")
        elif line.startswith("## "):
            parts.append(f"<h2>{html.escape(line[3:])}</h2>")
        elif line.startswith("- "):
            parts.append(f"<li>{html.escape(line[2:])}</li>")
        elif line.startswith("**"):
            parts.append(f"<p><b>{html.escape(line.strip('*'))}</b></p>")
        elif line:
            parts.append(f"<p>{html.escape(line)}</p>")
    flush()
    parts.append("<h2>Figures</h2>")
    for name, data in figs.items():
        parts.append(f"<p><img alt='{name}' src='data:image/png;base64,{base64.b64encode(data).decode()}'></p>")
    return "\n".join(parts) + "</body></html>\n"
