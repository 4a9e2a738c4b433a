"""Reports: CMA-ES progress plot."""

from __future__ import annotations

import io
from typing import Any, Sequence

import numpy as np


def plot_history(histories: Sequence[Sequence[dict[str, Any]]], title: str = "CMA-ES") -> bytes:
    """PNG of CMA-ES progress averaged over scenes: best-so-far and population-mean fitness
    and the best-so-far full-sequence IoU against the iteration.

    Args:
        histories: per scene, the ``history`` list of :func:`cmaes_refine`.
        title: figure title.
    Returns:
        PNG bytes (matplotlib, Agg backend), to write atomically.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    histories = [h for h in histories if h]
    fig, (ax_f, ax_i) = plt.subplots(1, 2, figsize=(9, 3.4))
    if histories:
        n_it = min(len(h) for h in histories)

        def mean_of(key: str) -> np.ndarray:
            vals = np.array([[e[key] for e in h[:n_it]] for h in histories], dtype=np.float64)
            vals[~np.isfinite(vals)] = np.nan
            return np.nanmean(vals, axis=0) if np.isfinite(vals).any() else np.full(n_it, np.nan)

        it = np.arange(n_it)
        ax_f.plot(it, mean_of("best_fitness"), "o-", label="best so far")
        ax_f.plot(it, mean_of("mean_fitness"), "s--", alpha=0.7, label="population mean")
        ax_i.plot(it, mean_of("best_full_iou"), "o-", color="tab:green")
        ax_f.legend(fontsize=8)
        evals = np.mean([h[n_it - 1]["evaluations"] for h in histories])
        fig.suptitle(f"{title}: mean over {len(histories)} scenes, {evals:.0f} evaluations each", fontsize=10)
    else:
        for ax in (ax_f, ax_i):
            ax.text(0.5, 0.5, "no scene was refined", ha="center", va="center", transform=ax.transAxes)
        fig.suptitle(title, fontsize=10)
    ax_f.set(xlabel="iteration", ylabel="fitness (IoU − λ·EPE)")
    ax_i.set(xlabel="iteration", ylabel="full-sequence IoU of the best")
    for ax in (ax_f, ax_i):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return buf.getvalue()
