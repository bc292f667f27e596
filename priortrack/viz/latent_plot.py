"""The latent space of a GPDM: training trajectories over the reconstruction-variance map.

As in Wang et al. (PAMI 2008, Figs. 4–6) and Urtasun et al. (CVPR 2006, Fig. 2): the first two
latent dimensions, each training sequence's latent path drawn as a line, over ln σ²(x), the
log variance of the reconstruction GP, light where it is low (where the model is sure of the pose
it decodes).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.backend_bases import FigureCanvasBase  # noqa: E402

from priortrack.output import output_path  # noqa: E402
from priortrack.priors.gpdm import GPDM  # noqa: E402


def plot_latent(model: GPDM, path: str | Path, n: int = 80) -> Path:
    """Write a PNG (or any format matplotlib infers from ``path``) of ``model``'s latent
    trajectories (dims 0 and 1) over its log reconstruction-variance map on an n × n grid
    (other latent dims at their training mean). Returns the path; a suffix matplotlib cannot
    write is a ``PriortrackError``, raised before anything is drawn."""
    path = output_path(path, "plot", suffixes=(f".{f}" for f in FigureCanvasBase.get_supported_filetypes()))
    gx, gy, logvar = (t.numpy() for t in model.log_variance_grid(n=n))
    X = model.X.numpy()
    fig, ax = plt.subplots(figsize=(6.4, 5.6), dpi=110)
    image = ax.pcolormesh(gx, gy, logvar, cmap="gray_r", shading="auto")
    fig.colorbar(image, ax=ax, label="ln σ²(x)  (reconstruction variance)")
    colours = plt.get_cmap("tab10")
    ends = np.cumsum(model.lengths)
    for s, (start, end) in enumerate(zip(ends - np.asarray(model.lengths), ends)):
        c = colours(s % 10)
        ax.plot(X[start:end, 0], X[start:end, 1], "-", color=c, lw=1.0)
        ax.plot(X[start:end, 0], X[start:end, 1], ".", color=c, ms=3)
        ax.plot(X[start, 0], X[start, 1], "o", color=c, ms=5, mfc="none")
    ax.set_xlabel("x0")
    ax.set_ylabel("x1")
    ax.set_aspect("equal", adjustable="box")
    ax.set_title(f"{model.kind}: N = {len(X)} frames, D = {model.D}, d = {model.d}, {len(model.lengths)} sequences")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
