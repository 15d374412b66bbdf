"""Figures (matplotlib, Agg backend); imported only by the CLI and scripts."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(plt, fig, path) -> Path:
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def estimation_figure(path, t, *, y=None, x_true=None, x_hat=None, alpha_true=None, alpha_hat=None,
                      alpha_sd=None, w_true=None, w_hat=None, w_sd=None, title="", state_label="state",
                      zoom=None) -> Path:
    """Three stacked panels like the paper's Figs. 2–4 / 12–14: state, order, parameter.

    ``zoom`` = (t0, t1) limits the state panel (a dense noise trace is unreadable over the whole run).
    """
    plt = pyplot()
    fig, ax = plt.subplots(3, 1, figsize=(9, 8), sharex=False)
    sel = slice(None) if zoom is None else (t >= zoom[0]) & (t <= zoom[1])
    if y is not None:
        ax[0].plot(t[sel], y[sel], lw=0.6, color="0.7", label="measurement y")
    if x_true is not None:
        ax[0].plot(t[sel], x_true[sel], lw=1.0, color="k", label="original x")
    if x_hat is not None:
        ax[0].plot(t[sel], x_hat[sel], lw=1.0, color="C3", ls="--", label="estimate x̂")
    ax[0].set_ylabel(state_label)
    ax[0].legend(loc="upper right", fontsize=8)
    for panel, true, est, sd, name in ((ax[1], alpha_true, alpha_hat, alpha_sd, "order α"),
                                        (ax[2], w_true, w_hat, w_sd, "parameter w")):
        if true is not None:
            panel.plot(t, true, color="k", lw=1.2, label="original")
        if est is not None:
            panel.plot(t, est, color="C3", lw=1.0, label="estimate")
            if sd is not None:
                panel.fill_between(t, est - 2 * sd, est + 2 * sd, color="C3", alpha=0.15, lw=0, label="±2σ (filter)")
        panel.set_ylabel(name)
        panel.legend(loc="upper right", fontsize=8)
    ax[2].set_xlabel("time [s]")
    ax[0].set_title(title)
    return save_figure(plt, fig, path)


def fan_figure(path, t, truth, runs, *, ylabel, title=""):
    """Median and 5–95 % / 25–75 % bands of many estimated trajectories ``runs (R, N)`` against the truth.

    Saves to ``path`` and returns it; with ``path=None`` returns the open matplotlib figure instead
    (e.g. for TensorBoard's ``add_figure``, which closes it)."""
    plt = pyplot()
    import torch  # numpy's nanquantile loops over the columns in Python (3000 calls for 3000 steps); torch's is one sort

    q = torch.nanquantile(torch.as_tensor(np.asarray(runs, dtype=np.float64)),
                          torch.tensor([0.05, 0.25, 0.5, 0.75, 0.95], dtype=torch.float64), dim=0).numpy()
    fig, ax = plt.subplots(figsize=(9, 3.5))
    ax.fill_between(t, q[0], q[4], color="C0", alpha=0.2, lw=0, label="5–95 %")
    ax.fill_between(t, q[1], q[3], color="C0", alpha=0.4, lw=0, label="25–75 %")
    ax.plot(t, q[2], color="C0", lw=1.0, label="median")
    if truth is not None:
        ax.plot(t, truth, color="k", lw=1.2, label="original")
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(loc="upper right", fontsize=8)
    if path is None:
        fig.tight_layout()
        return fig
    return save_figure(plt, fig, path)
