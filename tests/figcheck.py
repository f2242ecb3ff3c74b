"""What a reader relies on in a figure: every panel shows data from each filter mode its legend names."""

import numpy as np
from matplotlib.colors import to_rgba

from gpsins.report.data import MODE_COLORS


def _finite_points(artist) -> int:
    if hasattr(artist, "get_ydata"):
        y = np.asarray(artist.get_ydata(), dtype=float)
        return int(np.isfinite(y).sum())
    paths = artist.get_paths() if hasattr(artist, "get_paths") else []
    return sum(int(np.isfinite(p.vertices).all(axis=1).sum()) for p in paths)


def mode_points(ax, mode: str) -> int:
    """Finite points drawn in the mode's colour on this axes (lines, bands, markers)."""
    want = to_rgba(MODE_COLORS[mode])[:3]
    n = 0
    for line in ax.get_lines():
        if np.allclose(to_rgba(line.get_color())[:3], want):
            n += _finite_points(line)
    for coll in ax.collections:
        fc = coll.get_facecolor()
        if len(fc) and np.allclose(fc[0][:3], want):
            n += _finite_points(coll)
    return n


def legend_modes(ax) -> set[str]:
    legend = ax.get_legend()
    if legend is None:
        return set()
    texts = [t.get_text() for t in legend.get_texts()]
    return {m for m in MODE_COLORS for t in texts if t == m or t.startswith(m + " ")}


def check_figure(name: str, fig) -> dict:
    """Raise if a panel lacks data of a mode its legend (or the figure's first legend) names; returns what it found."""
    axes = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    first = next((legend_modes(ax) for ax in axes if ax.get_legend() is not None), set())
    found = {}
    for k, ax in enumerate(axes):
        modes = legend_modes(ax) if ax.get_legend() is not None else first
        for m in modes:
            n = mode_points(ax, m)
            assert n >= 2, f"{name}: panel {k} ({ax.get_ylabel() or ax.get_title()}) names {m} but shows {n} points"
            found[(k, m)] = n
    return found
