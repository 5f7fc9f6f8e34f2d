"""Plots of a run (matplotlib, headless)."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np

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


def _xy(states):
    """(N, 2) base positions of a list of 8-vector states, or None when there are none."""
    import numpy as np
    if not states:
        return None
    a = np.asarray(states, float).reshape(-1, 8)
    return a[:, :2]


def plot_paths(records: list[dict], path: Path, scene_cfg, title: str = "", min_error: float = 0.002,
               collision: dict | None = None):
    """Top view (x, y) of a run, after Vasquez-Gomez et al. 2017 Fig. 17: the table (or the support box;
    nothing on the floor), W_box and the other known
    obstacles (cluttered_room's chairs; their names are returned), per iteration
    the planned base path (dashed; the plan made after scan k) and the executed true path
    (solid; the motion that ended at scan k + 1) in one colour, the true base pose at each
    scan (numbered, with its heading), and the believed (dead-reckoned, x) and corrected
    (after re-localisation, +) positions where the records have them and they lie more than
    `min_error` (m) from the true one. Records without path fields still give the numbered
    scan positions. `collision` (summary.json's): the colliding trajectory's executed path up
    to the collision, in red, and the true pose where it stopped."""
    import numpy as np
    from matplotlib.patches import Polygon, Rectangle

    fig, ax = plt.subplots(figsize=(6.4, 6.0), dpi=110)
    pts = []  # everything drawn, for the limits
    support = getattr(scene_cfg, "support", "table")
    if support in ("table", "box"):  # what the object stands on (nothing drawn for the floor)
        tx, ty = scene_cfg.table_size if support == "table" else scene_cfg.box_size[:2]
        cx, cy = (0.0, 0.0) if support == "table" else scene_cfg.object.xy
        ax.add_patch(Rectangle((cx - tx / 2, cy - ty / 2), tx, ty, facecolor=(0.82, 0.7, 0.55),
                               edgecolor=(0.55, 0.4, 0.25), lw=1, zorder=0, label=support))
        pts.append(np.array([[cx - tx / 2, cy - ty / 2], [cx + tx / 2, cy + ty / 2]]))
    lo, hi = scene_cfg.bbox_min, scene_cfg.bbox_max
    ax.add_patch(Rectangle((lo[0], lo[1]), hi[0] - lo[0], hi[1] - lo[1], fill=False, edgecolor="0.3", lw=1,
                           ls=":", zorder=1, label="$W_{box}$"))
    cmap = plt.get_cmap("viridis")
    n = max(len(records), 2)
    by_iter = {r.get("iteration", i + 1): r for i, r in enumerate(records)}
    labelled = set()

    def once(key, text):
        if key in labelled:
            return None
        labelled.add(key)
        return text

    # the rest of the known environment (cluttered_room's chairs), as footprints
    from ..world.pose import rot_z
    from ..world.scene import environment_boxes
    obstacles = []
    for b in environment_boxes(scene_cfg):
        if b.name == "floor" or b.name.startswith(("table", "support")):
            continue
        local = 0.5 * np.array(b.size[:2]) * np.array([(-1, -1), (1, -1), (1, 1), (-1, 1)])
        corners = np.array(b.center[:2]) + local @ rot_z(b.yaw)[:2, :2].T
        kind = "chairs" if b.name.startswith("chair") else "obstacles"
        ax.add_patch(Polygon(corners, closed=True, facecolor=(0.62, 0.68, 0.85), edgecolor=(0.2, 0.3, 0.6),
                             lw=0.8, zorder=0, label=once(kind, kind)))
        obstacles.append(b.name)
        pts.append(corners)

    for i, rec in enumerate(records):
        k = rec.get("iteration", i + 1)
        col = cmap(i / (n - 1) * 0.9)
        plan = rec.get("plan") or {}
        planned = _xy(plan.get("path")) if plan.get("status") == "ok" else None
        if planned is not None:
            ax.plot(planned[:, 0], planned[:, 1], "--", color=col, lw=1.3, zorder=4,
                    label=once("plan", "planned path"))
            pts.append(planned)
        nxt = by_iter.get(k + 1)
        executed = _xy(nxt.get("executed_path")) if nxt else None
        if executed is not None:
            ax.plot(executed[:, 0], executed[:, 1], "-", color=col, lw=3.0, alpha=0.5, zorder=3,
                    label=once("exec", "executed path (true)"))
            pts.append(executed)
        true = rec.get("true_state")
        if true:
            x, y, th = true[0], true[1], true[2]
            ax.plot(x, y, "o", ms=13, mfc="white", mec=col, mew=2, zorder=5,
                    label=once("scan", "true pose at scan k"))
            ax.annotate("", xy=(x + 0.16 * np.cos(th), y + 0.16 * np.sin(th)), xytext=(x, y), zorder=5,
                        arrowprops={"arrowstyle": "->", "color": col, "lw": 1.2})
            ax.text(x, y, str(k), ha="center", va="center", fontsize=7, zorder=8)
            pts.append(np.array([[x, y]]))
        bel = rec.get("believed_state")
        if bel and true and np.hypot(bel[0] - true[0], bel[1] - true[1]) > min_error:
            ax.plot(bel[0], bel[1], "x", color="crimson", ms=7, mew=1.5, zorder=6,
                    label=once("bel", "believed (dead reckoning)"))
            ax.plot([true[0], bel[0]], [true[1], bel[1]], "-", color="crimson", lw=0.7, zorder=5)
            pts.append(np.array([bel[:2]]))
        cor = rec.get("corrected_state")
        if cor and true and np.hypot(cor[0] - true[0], cor[1] - true[1]) > min_error:
            ax.plot(cor[0], cor[1], "+", color="darkorange", ms=9, mew=1.8, zorder=6,
                    label=once("cor", "corrected (ICP)"))
            pts.append(np.array([cor[:2]]))
    hit = _xy((collision or {}).get("executed_path"))
    if hit is not None:
        ax.plot(hit[:, 0], hit[:, 1], "-", color="red", lw=2.0, zorder=6, label="executed until the collision")
        pts.append(hit)
    stop = (collision or {}).get("true_state")
    if stop:
        ax.plot(stop[0], stop[1], "X", color="red", ms=11, mec="black", zorder=9, label="collision (true pose)")
        pts.append(np.array([stop[:2]]))
    allp = np.concatenate(pts + [np.array([lo[:2], hi[:2]], float)])
    pad = 0.3
    x0, x1 = allp[:, 0].min() - pad, allp[:, 0].max() + pad
    y0, y1 = allp[:, 1].min() - pad, allp[:, 1].max() + pad
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    # the figure follows the data's aspect (plus room for the legend below)
    fig.set_size_inches(6.4, float(np.clip(5.0 * (y1 - y0) / (x1 - x0), 2.5, 8.0)) + 1.6)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(alpha=0.3)
    leg = ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=3, fontsize=7, framealpha=0.9)
    for h, text in zip(leg.legend_handles, leg.get_texts()):  # iteration colours: neutral in the legend
        if text.get_text() in ("planned path", "executed path (true)"):
            h.set_color("0.35")
        elif text.get_text() == "true pose at scan k":
            h.set_markeredgecolor("0.35")
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return obstacles


def carry_forward(per_run: list[list[float]]) -> np.ndarray:
    """(runs, longest run) coverage per scan; a run that stopped early (a collision, no
    view) keeps its last coverage for the scans it did not take, as its final model does."""
    out = np.zeros((len(per_run), max(len(c) for c in per_run)))
    for i, c in enumerate(per_run):
        out[i, : len(c)] = c
        out[i, len(c):] = c[-1]
    return out


def draw_coverage_by_scenario(ax, series: dict[str, list[list[float]]], title: str = ""):
    """Draws on `ax` the mean coverage per scan over each scenario's runs (series: scenario
    -> per run its coverage_by_scan), +- one standard deviation (Vasquez-Gomez et al. 2017 Fig. 12); runs that
    stopped early count with their last coverage (the legend says how many stopped)."""
    for name, per_run in series.items():
        a = 100 * carry_forward(per_run)
        k = np.arange(1, a.shape[1] + 1)
        m, s = a.mean(0), a.std(0)
        short = sum(len(c) < a.shape[1] for c in per_run)
        label = f"{name} ({len(per_run)} runs" + (f", {short} stopped early)" if short else ")")
        ax.plot(k, m, "o-", ms=3, label=label)
        ax.fill_between(k, m - s, m + s, alpha=0.15)
    ax.set_xlabel("scan")
    ax.set_ylabel("mean surface coverage, 3 mm (%)")
    ax.set_ylim(0, 100)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(title)
