"""A small plot of the geometry optimisation's loss terms per iteration (PNG bytes)."""

from __future__ import annotations

import io

import numpy as np

TERMS = ("total", "penetration_pairs", "penetration_table", "contact", "anchor", "free_space")


def loss_plot(history: dict[str, list[float]], title: str = "geometry optimisation") -> bytes:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5), dpi=100)
    for name in TERMS:
        values = np.asarray(history.get(name, []), dtype=float)
        if values.size and np.any(values > 0):
            ax.semilogy(np.arange(values.size), np.maximum(values, 1e-6), label=name,
                        lw=2.0 if name == "total" else 1.0)
    ax.set_xlabel("iteration")
    ax.set_ylabel("loss (mm-scaled)")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    if ax.get_lines():  # all terms zero (nothing to optimise): an empty plot, no legend
        ax.legend(fontsize=7)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()
