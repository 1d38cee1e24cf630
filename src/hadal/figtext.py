"""Legible text on matplotlib figures: the smallest font a figure may carry (report and landing figures)."""

from __future__ import annotations

from typing import Any

#: smallest text (points) on a report or landing figure. The figures are drawn at 110 dpi and at most ~1100 px wide,
#: so the page (max 1100 px) shows them at >= ~97 % of their size: 9 pt stays >= 9 pt (12 CSS px) on screen
MIN_FONT_PT = 9.0


def min_fonts(fig: Any, min_pt: float = MIN_FONT_PT) -> None:
    """Raise every text of ``fig`` (titles, labels, tick labels, legends, annotations, colour-bar labels) smaller
    than ``min_pt`` points to ``min_pt``."""
    from matplotlib.text import Text

    for ax in fig.get_axes():
        for name, axis in (("x", ax.xaxis), ("y", ax.yaxis)):
            ticks = axis.get_major_ticks() + axis.get_minor_ticks()
            if any(t.label1.get_fontsize() < min_pt for t in ticks):
                ax.tick_params(axis=name, which="both", labelsize=min_pt)
    for t in fig.findobj(Text):
        if t.get_fontsize() < min_pt:
            t.set_fontsize(min_pt)
