"""The Monte Carlo figure of one (mode, value) group: the run-averaged 9-state NEES in its
chi-square band over time, and the error RMS across runs next to the filter's own sigma."""

from __future__ import annotations

from pathlib import Path


def draw(group: dict, path: Path, title: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    nees = group["nees9"]
    s, ser = nees["series"], group["series"]
    t = ser["t_s"]
    fig, axs = plt.subplots(2, 1, figsize=(10, 7), sharex=True, constrained_layout=True)
    ax = axs[0]
    ax.fill_between(t, s["lower"], s["upper"], color="0.6", alpha=0.35, step="mid",
                    label=f"{100 * (1 - nees['alpha']):.0f} % band of a {nees['runs']}-run average")
    ax.semilogy(t, s["mean"], color="C0", lw=1, label=f"NEES, average over runs ({nees['fraction_inside']:.0%} "
                                                       f"of {nees['epochs']} epochs inside)")
    ax.axhline(nees["dof"], color="k", ls=":", lw=1, label=f"expected ({nees['dof']})")
    ax.set_ylabel("9-state NEES")
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    ax = axs[1]
    for err, sigma, color, name in (("h_rms_m", "sigma_h_rms_m", "C1", "horizontal"),
                                    ("v_rms_m", "sigma_v_rms_m", "C2", "vertical")):
        ax.plot(t, ser[err], color=color, lw=1, label=f"{name} error, RMS across runs")
        ax.plot(t, ser[sigma], color=color, lw=1, ls="--", label=f"{name} sigma of the filter, RMS across runs")
    _segments(ax, group.get("segments", []))
    for o in group.get("outages", []):
        for a in axs:
            a.axvspan(o["start_s"], o["end_s"], color="C3", alpha=0.12, lw=0)
    if group.get("outages"):
        axs[0].plot([], [], color="C3", alpha=0.3, lw=6, label="GNSS outages")
        axs[0].legend(loc="upper right", fontsize=8)
    ax.set_yscale("log")
    ax.set_xlabel("time since the scenario's start, s")
    ax.set_ylabel("position error, m")
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    axs[0].set_title(title)
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _segments(ax, segments: list[dict]) -> None:
    """Segment boundaries as faint lines, labelled when there are few enough to read."""
    for seg in segments[1:]:
        ax.axvline(seg["t0_s"], color="0.8", lw=0.6, zorder=0)
    if 0 < len(segments) <= 30:
        for seg in segments:
            ax.text(0.5 * (seg["t0_s"] + seg["t1_s"]), 0.02, seg["label"], transform=ax.get_xaxis_transform(),
                    ha="center", va="bottom", fontsize=6, rotation=90, color="0.4", clip_on=True)
