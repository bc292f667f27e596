"""The latent space of a GPDM: training trajectories over the reconstruction-variance map.

As in Wang et al. (PAMI 2008, Figs. 4–6) and Urtasun et al. (CVPR 2006, Fig. 2): the first two
latent dimensions, each training sequence's latent path drawn as a line, over ln σ²(x), the
log variance of the reconstruction GP, light where it is low (where the model is sure of the pose
it decodes).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.backend_bases import FigureCanvasBase
from matplotlib.figure import Figure

from priortrack.output import output_path
from priortrack.priors.gpdm import GPDM


def draw_latent(model: GPDM, ax, n: int = 80) -> None:
    """Draw ``model``'s latent trajectories (dims 0 and 1) over its log reconstruction-variance map
    on an n × n grid (other latent dims at their training mean) into the matplotlib axes ``ax``
    (a notebook's, inline)."""
    gx, gy, logvar = (t.numpy() for t in model.log_variance_grid(n=n))
    X = model.X.numpy()
    image = ax.pcolormesh(gx, gy, logvar, cmap="gray_r", shading="auto")
    ax.figure.colorbar(image, ax=ax, label="ln σ²(x)  (reconstruction variance)")
    colours = colormaps["tab10"]
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


def plot_latent(model: GPDM, path: str | Path, n: int = 80) -> Path:
    """Write :func:`draw_latent`'s figure as a PNG (or any format matplotlib infers from ``path``),
    without pyplot (the caller's backend is left alone). Returns the path; a suffix matplotlib cannot
    write is a ``PriortrackError``, raised before anything is drawn."""
    path = output_path(path, "plot", suffixes=(f".{f}" for f in FigureCanvasBase.get_supported_filetypes()))
    fig = Figure(figsize=(6.4, 5.6), dpi=110)
    draw_latent(model, fig.subplots(), n)
    fig.tight_layout()
    fig.savefig(path)
    return path
