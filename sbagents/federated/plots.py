"""The rounds plot of a federated run: the held-out homes' comfort share and success rate per round."""

from __future__ import annotations

import csv
from pathlib import Path


def plot_rounds(rounds_csv: Path, out: Path, title: str) -> Path | None:
    """Draw ``rounds.csv`` into ``out`` (PNG); None when the file has no held-out evaluation."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with rounds_csv.open(newline="") as f:
        rows = [r for r in csv.DictReader(f) if r.get("heldout_criterion_share")]
    if not rows:
        return None
    rounds = [int(r["round"]) for r in rows]
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(rounds, [float(r["heldout_criterion_share"]) for r in rows], marker="o", label="comfort share")
    ax.plot(rounds, [float(r["heldout_success_rate"]) for r in rows], marker="s", label="success (>= 97%)")
    ax.axhline(0.95, color="grey", linestyle=":", linewidth=1, label="95%")
    ax.set(xlabel="round", ylabel="held-out homes", ylim=(-0.02, 1.02), title=title)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out
