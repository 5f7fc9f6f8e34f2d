"""An experiment's figures, drawn like the papers' (matplotlib, headless):

- `series`: a per-iteration series' mean over each cell's runs with a band of one standard
  deviation, one curve per cell, optionally one panel per level of a factor (`panels`), e.g.
  Vasquez-Gomez et al. 2017 Figs. 9, 10 and 12, the ORT paper's Figs. 6-8 and 10-12;
- `versus`: a metric against the levels' `x` (Vasquez-Gomez et al. 2017 Fig. 11: collision
  rate against k); cells without an `x` are drawn as horizontal reference lines;
- `bars`: a metric's mean per cell with each seed's value as a dot;
- `scatter`: the prediction analysis (Santos et al. 2020 Fig. 11): predicted against revealed
  unknown volume, the ideal line and the least-squares line with its R².

A `series` figure may name `levels` ({factor: [labels]}): only the cells at those levels are
drawn (an experiment whose trials would crowd the legend draws its rungs and its preset).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..outputs.plots import plt


def _series_of(table: dict, cell_idx: int, name: str):
    c = table["cells"][cell_idx]
    if name in c["series"]:
        return c["series"][name]
    return table["timings"]["cells"][cell_idx]["series"].get(name)


def _spec(r: dict, name: str) -> dict:
    for sec in ("series", "timings", "metrics"):
        for s in r.get(sec) or []:
            if s["name"] == name:
                return s
    return {"name": name}


def _axis_label(spec: dict, name: str) -> str:
    return spec.get("label", name.replace("_", " ")) + (f" ({spec['unit']})" if spec.get("unit") else "")


def _curve_label(levels: dict, skip: str | None) -> str:
    """'DU-MU', 'teapot/EU-MU'; a number is named by its factor: 'k = 2500'."""
    def one(k, v):
        try:
            float(v)
            return f"{k} = {v}"
        except ValueError:
            return v
    return "/".join(one(k, v) for k, v in levels.items() if k != skip) or "all"


def _panels(table: dict, panel_f: str | None) -> list[str]:
    """The levels of the factor `panel_f` in the table's cells, in order ([""]: no panels)."""
    return list(dict.fromkeys(c["levels"].get(panel_f, "") for c in table["cells"])) if panel_f else [""]


def draw_series(r, table, fig_spec, path: Path):
    name = fig_spec["series"]
    spec = _spec(r, name)
    panel_f = fig_spec.get("panels")
    panels = _panels(table, panel_f)
    fig, axes = plt.subplots(1, len(panels), figsize=(5.6 * len(panels), 4.0), dpi=110, squeeze=False)
    only = fig_spec.get("levels") or {}
    for ax, pv in zip(axes[0], panels):
        for i, c in enumerate(table["cells"]):
            if panel_f and c["levels"].get(panel_f) != pv:
                continue
            if any(c["levels"].get(f) not in [str(x) for x in labels] for f, labels in only.items()):
                continue
            s = _series_of(table, i, name)
            if not s or not s["mean"]:
                continue
            m = np.array([np.nan if v is None else v for v in s["mean"]], float)
            sd = np.array([np.nan if v is None else v for v in s["std"]], float)
            k = np.arange(1, len(m) + 1)
            runs = max(s["n"]) if s["n"] else 0
            line, = ax.plot(k, m, "o-", ms=3, label=f"{_curve_label(c['levels'], panel_f)} "
                                                    f"({runs} run{'s' if runs != 1 else ''})")
            ax.fill_between(k, m - sd, m + sd, alpha=0.15, color=line.get_color())
        from matplotlib.ticker import MaxNLocator
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_xlabel(fig_spec.get("xlabel", "iteration (scan)"))
        ax.set_ylabel(fig_spec.get("ylabel") or spec.get("label", name.replace("_", " ")) +
                      (f" ({spec['unit']})" if spec.get("unit") else ""))
        if fig_spec.get("ylim"):
            ax.set_ylim(*fig_spec["ylim"])
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc=fig_spec.get("legend", "best"))
        ax.set_title(": ".join(x for x in (pv, fig_spec.get("title", "")) if x))
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _metrics_of(table: dict, i: int) -> dict:
    """A cell's metrics and timing metrics together."""
    return dict(table["timings"]["cells"][i]["metrics"], **table["cells"][i]["metrics"])


def _metric_point(c: dict, name: str, stat: str | None):
    st = c["metrics"].get(name) or {}
    stat = stat or ("pooled" if "pooled" in st else "mean")
    return st.get(stat), (st.get("std") if stat == "mean" else None)


def draw_versus(r, table, fig_spec, path: Path):
    name, stat = fig_spec["metric"], fig_spec.get("stat")
    spec = _spec(r, name)
    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=110)
    group_f = fig_spec.get("group")  # a factor whose levels each get one curve
    xs = {}
    cells_m = [dict(c, metrics=_metrics_of(table, i)) for i, c in enumerate(table["cells"])]
    for c in cells_m:
        if c.get("x") is None:
            continue
        key = c["levels"].get(group_f, "") if group_f else fig_spec.get("curve_label", "")
        xs.setdefault(key, []).append(c)
    for key, cs in xs.items():
        cs = sorted(cs, key=lambda c: float(c["x"]))
        pts = [(float(c["x"]),) + _metric_point(c, name, stat) for c in cs]
        pts = [p for p in pts if p[1] is not None]
        if not pts:
            continue
        x, y, e = zip(*pts)
        ax.errorbar(x, y, yerr=None if all(v is None for v in e) else [v or 0 for v in e], fmt="o-", ms=4,
                    capsize=3, label=key or name)
    pub = []
    for i, c in enumerate(table["cells"]):
        pubs = dict(table["timings"]["cells"][i].get("published") or {}, **(c.get("published") or {}))
        v = pubs.get(f"{name}.{stat or 'mean'}", pubs.get(name))
        if c.get("x") is not None and v is not None:
            pub.append((float(c["x"]), float(v)))
    if pub:
        px, py = zip(*sorted(pub))
        ax.plot(px, py, "s--", color="crimson", ms=5, lw=1, label="paper")
    for c in cells_m:
        if c.get("x") is not None:
            continue
        y, _ = _metric_point(c, name, stat)
        if y is not None:
            ax.axhline(y, ls="--", lw=1.2, color=f"C{(len(xs) + 3 + cells_m.index(c)) % 10}", label=c["label"])
    if fig_spec.get("bound") == "eq18" and xs:
        # Vasquez-Gomez et al. 2017 eq. 18 read the other way: with k rollouts, a trajectory
        # whose error region meets the obstacles with probability gamma >= (1 - alpha^(1/k)) / eta
        # is caught with confidence 1 - alpha; below that it may pass (eta = 1 / 0.997)
        alpha, eta = float(fig_spec.get("alpha", 0.01)), 1 / 0.997
        allx = [float(c["x"]) for cs in xs.values() for c in cs]
        k = np.geomspace(max(min(allx), 1.0), max(allx), 200)
        ax.plot(k, 100 * (1 - alpha ** (1 / k)) / eta, ":", color="0.3", lw=1.5,
                label=f"eq. 18 bound on undetected collision probability (alpha = {alpha:g})")
    if fig_spec.get("xscale"):
        ax.set_xscale(fig_spec["xscale"])
    ax.set_xlabel(fig_spec.get("xlabel", "x"))
    ax.set_ylabel(fig_spec.get("ylabel") or _axis_label(spec, name))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(fig_spec.get("title", ""))
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def draw_bars(r, table, fig_spec, path: Path):
    """One bar per cell (the mean, the runs as dots, the paper's value as a red line); with
    `panels: FACTOR`, one row of bars per level of that factor, its cells labelled without
    it."""
    name = fig_spec["metric"]
    spec = _spec(r, name)
    panel_f = fig_spec.get("panels")
    cells = table["cells"]
    panels = _panels(table, panel_f)
    rows = [[i for i, c in enumerate(cells) if not panel_f or c["levels"].get(panel_f, "") == pv] for pv in panels]
    width = max(len(row) for row in rows)
    fig, axes = plt.subplots(len(panels), 1, figsize=(max(4.0, 1.1 * width + 2), 4.0 * len(panels)), dpi=110,
                             squeeze=False)
    for ax, pv, row in zip(axes[:, 0], panels, rows):
        for x, i in enumerate(row):
            st = _metrics_of(table, i).get(name) or {}
            pubs = dict(table["timings"]["cells"][i].get("published") or {}, **(cells[i].get("published") or {}))
            if st.get("mean") is not None:
                ax.bar(x, st["mean"], 0.6, color="C0", alpha=0.7)
            vals = list((st.get("values") or {}).values())
            ax.plot([x] * len(vals), vals, "k.", ms=5)
            pub = pubs.get(f"{name}.mean", pubs.get(name))
            if pub is not None:
                ax.plot([x - 0.3, x + 0.3], [pub, pub], "r-", lw=2, label="paper")
        labels = [_curve_label(cells[i]["levels"], panel_f) if panel_f else cells[i]["label"] for i in row]
        ax.set_xticks(range(len(row)), labels, rotation=20, fontsize=8)
        ax.set_ylabel(fig_spec.get("ylabel") or _axis_label(spec, name))
        ax.grid(alpha=0.3, axis="y")
        h, lab = ax.get_legend_handles_labels()
        if h:
            ax.legend(h[:1], lab[:1], fontsize=8)
        ax.set_title(f"{fig_spec.get('title', '')}: {pv}" if panel_f else fig_spec.get("title", ""))
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def draw_scatter(r, table, fig_spec, path: Path):
    fig, ax = plt.subplots(figsize=(5.2, 5.0), dpi=110)
    allp = []
    for c in table["cells"]:
        p = c.get("prediction") or {}
        pts = np.array(p.get("pairs") or [], float).reshape(-1, 2)
        if len(pts):
            ax.plot(pts[:, 0], pts[:, 1], "o", ms=4, alpha=0.7, label=f"{c['label']} ({len(pts)})")
            allp.append(pts)
    an = (table.get("analysis") or {}).get("prediction") or {}
    if allp:
        a = np.concatenate(allp)
        hi = float(max(a.max(), 1e-6)) * 1.05
        lo = min(0.0, float(a.min()))
        ax.plot([lo, hi], [lo, hi], "g--", lw=1, label="ideal (revealed = predicted)")
        if an.get("slope") is not None:
            ax.plot([lo, hi], [an["slope"] * lo + an["intercept"], an["slope"] * hi + an["intercept"]], "r-", lw=1.2,
                    label=f"fit: slope {an['slope']:.2f}, R² = {an['r2']:.3f}" if an.get("r2") is not None else "fit")
        ax.set_xlim(lo, hi)
        ax.set_ylim(lo, hi)
    ax.set_xlabel(fig_spec.get("xlabel", "predicted unknown volume (m³)"))
    ax.set_ylabel(fig_spec.get("ylabel", "revealed unknown volume (m³)"))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title(fig_spec.get("title", ""))
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


DRAW = {"series": draw_series, "versus": draw_versus, "bars": draw_bars, "scatter": draw_scatter}


def draw_figures(r: dict, table: dict, exp_dir: Path) -> list[str]:
    """Draws each figure of the definition into exp_dir; returns their file names. A
    figure that fails is skipped with a note (the table is what matters)."""
    out = []
    for f in r.get("figures") or []:
        if not table["runs_finished"]:
            break
        path = Path(exp_dir) / f["file"]
        try:
            DRAW[f["kind"]](r, table, f, path)
        except Exception as e:  # noqa: BLE001 - a figure must not lose the table
            table.setdefault("figure_errors", {})[f["file"]] = f"{type(e).__name__}: {e}"
            continue
        out.append(f["file"])
    return out
