"""Plots of a run (matplotlib, headless)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def plot_coverage(records: list[dict], path: Path, title: str = ""):
    """Coverage (3 mm, 5 mm, one voxel) and unknown voxels per scan."""
    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=110)
    k = [r["iteration"] for r in records]
    ax.plot(k, [100 * r["coverage"] for r in records], "o-", label="coverage (3 mm)")
    ax.plot(k, [100 * r["coverage_5mm"] for r in records], "s--", label="coverage (5 mm)", alpha=0.8)
    ax.plot(k, [100 * r["coverage_voxel"] for r in records], "^:", label="coverage (1 voxel)", alpha=0.8)
    ax.set_xlabel("scan")
    ax.set_ylabel("surface coverage (%)")
    ax.set_ylim(0, 100)
    ax.set_xticks(k)
    ax.grid(alpha=0.3)
    ax2 = ax.twinx()
    ax2.plot(k, [r["unknown_voxels"] for r in records], color="0.5", lw=1, label="unknown voxels")
    ax2.set_ylabel("unknown voxels", color="0.4")
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, loc="lower right", fontsize=8)
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
