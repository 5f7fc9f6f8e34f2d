"""`nbvs experiment --list` and `nbvs experiment report`: docs/results.md from the
experiments' table.md files, each stamped with the command, git commit and date that
produced it (from its table.json)."""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

from ..files import write_atomic
from .aggregate import TIMINGS_HEADING, load_table
from .definition import definition_names, expand, load_definition, resolve


def _fmt_s(s) -> str:
    if s is None:
        return "?"
    s = float(s)
    if s < 120:
        return f"{s:.0f} s"
    if s < 2 * 3600:
        return f"{s / 60:.0f} min"
    return f"{s / 3600:.1f} h"


def listing(defs: list | None = None) -> str:
    """One paragraph per built-in experiment (or per definition of `defs`: the benchmark's
    protocols): its paper, table/figure, number of runs (full and quick) and the measured cost
    per run."""
    lines = []
    for d in defs if defs is not None else [load_definition(n) for n in definition_names()]:
        name = d["name"]
        full, quick = len(expand(resolve(d))), len(expand(resolve(d, quick=True)))
        cost = d.get("cost") or {}
        q, f = cost.get("quick_run_s"), cost.get("full_run_s")
        lines.append(f"{name:13s} {d.get('paper', '')}, {d.get('reference', '')}: {d.get('title', '')}")
        kind = {"measured": "measured: the mean of the full runs", "derived": "derived from measured full runs"}.get(
            cost.get("full_kind"), "estimated from runs on the same machine")
        jobs = int(cost.get("jobs", 2))
        lines.append(f"{'':13s} full: {full} runs x ~{_fmt_s(f)} ({kind}; cost.full_basis in the definition) = "
                     f"~{_fmt_s(f * full)} of run time, ~{_fmt_s(f * full / jobs)} of wall time on 2 cores "
                     f"(--jobs {jobs})" if f
                     else f"{'':13s} full: {full} runs, cost per run not measured")
        lines.append(f"{'':13s} quick: {quick} runs, {_fmt_s(q)} per run (measured)" if q else
                     f"{'':13s} quick: {quick} runs")
        if cost.get("machine"):
            when = f", {cost['measured']}" if cost.get("measured") else ""
            lines.append(f"{'':13s} measured on {cost['machine']}{when}")
    return "\n".join(lines)


def _relink(md: str, src_dir: Path, dest: Path, figures: Path | None = None) -> str:
    """Figure links of a table.md made relative to the report's folder. With `figures`, each
    linked file that exists is copied there (figures/<experiment>/<file>) and linked there,
    so that the report does not point into an output folder that is not kept with it."""
    def sub(m):
        target = m.group(2)
        if re.match(r"^[a-z]+://", target) or target.startswith("/"):
            return m.group(0)
        src = src_dir / target
        if figures is not None and src.is_file():
            copy = figures / src_dir.name / src.name
            copy.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(src, copy)
            src = copy
        rel = os.path.relpath(src, dest.parent)
        return f"![{m.group(1)}]({rel})"
    return re.sub(r"!\[([^\]]*)\]\(([^)]+)\)", sub, md)


def _sections(marked: str) -> dict[str, str]:
    """The experiments' sections of a report's marked part, by experiment folder name (the
    word before the colon of each "## name: title" heading), each up to the next one."""
    out, name, lines = {}, None, []
    for line in marked.splitlines():
        m = re.match(r"^## ([A-Za-z0-9_.-]+)(?::|$)", line)
        if m:
            if name:
                out[name] = "\n".join(lines).rstrip()
            name, lines = m.group(1), []
        if name:
            lines.append(line)
    if name:
        out[name] = "\n".join(lines).rstrip()
    return out


#: where a hand-written results file keeps the generated part (all the rest is left as is)
BEGIN, END = "<!-- nbvs experiment report: begin -->", "<!-- nbvs experiment report: end -->"


def write_report(out_root, dest, figures=None) -> tuple[Path, list[str]]:
    """Assembles dest (docs/results.md) from out_root/*/table.md, built-in experiments
    first in their listing order (the full version, then the quick one), then any other.
    The tables' figures are copied to `figures` (default: dest's folder/figures/experiments)
    and linked there.
    A dest that holds the BEGIN and END markers keeps everything outside them (the "# Results"
    heading is then left to the file); otherwise dest is written whole. An experiment whose
    section the marked part already holds and whose table out_root lacks (run on another
    machine, its outputs not kept) keeps that section; one in out_root replaces it."""
    out_root, dest = Path(out_root), Path(dest)
    figures = Path(figures) if figures is not None else dest.parent / "figures" / "experiments"
    order = {n: i for i, n in enumerate(definition_names())}
    found = [p.parent for p in out_root.glob("*/table.json")]

    def key(d: Path):
        base = d.name[:-len("_quick")] if d.name.endswith("_quick") else d.name
        return (order.get(base, len(order)), base, d.name.endswith("_quick"))
    found.sort(key=key)
    if not found:
        from .definition import ExperimentError
        raise ExperimentError(f"no experiment tables (*/table.json) in {out_root}; {dest} left as it is")
    old = dest.read_text() if dest.is_file() else ""
    marked = BEGIN in old and END in old.split(BEGIN, 1)[1]
    kept = _sections(old.split(BEGIN, 1)[1].split(END, 1)[0]) if marked else {}
    parts = ["# Results", "",
             f"Assembled by `nbvs experiment report --to {dest}` from each experiment's `table.md` (an "
             "experiment whose table was not in the `--out` of the last call keeps its earlier section). Each "
             "table says which command, at which git commit and on which date, produced it. "
             "`nbvs experiment --list` lists the experiments and their cost.", ""]
    names = []
    sections = {}
    for d in found:
        t = load_table(d)
        st = t.get("stamp") or {}
        md = t.markdown.split("\nProvenance:", 1)[0].rstrip()
        md = _relink(md, d, dest, figures)
        stamp = (f"*Produced by* `{st.get('command') or '?'}` *at commit* `{st.get('git_commit', '?')}` "
                 f"*on* {st.get('date', '?')} ({st.get('executor', '?')}, {st.get('host', '?')}).")
        if st.get("run_commits"):
            stamp += f" *Runs made at:* {st['run_commits']}."
        first, _, rest = md.partition("\n")
        # headed by the folder's name (a quick version's table has the full one's name)
        title = first.split(":", 1)[1] if ":" in first else ""
        sections[d.name] = "\n".join([f"## {d.name}:{title}".rstrip(":"), "", stamp,
                                      rest.replace(TIMINGS_HEADING, "#" + TIMINGS_HEADING)]).rstrip()
        names.append(d.name)
    for name in sorted(set(sections) | set(kept), key=lambda n: key(Path(n))):
        parts += [sections.get(name) or kept[name], ""]
    text = "\n".join(parts).rstrip() + "\n"
    if marked:  # only the marked part is ours
        head, rest = old.split(BEGIN, 1)
        text = head + BEGIN + "\n" + text.split("\n", 1)[1].lstrip("\n") + END + rest.split(END, 1)[1]
    write_atomic(dest, text, mkdir=True)
    return dest, names
