"""docs/configuration.md, written from the schema's own docstrings and `#:` comments
(`nbvs config-reference`); a test holds the file equal to what this writes."""

from __future__ import annotations

import ast
import dataclasses as dc
import inspect
import typing
from pathlib import Path

from . import schema as S
from .load import PRESETS_DIR, preset_names


def _field_comments(cls) -> dict[str, str]:
    """{field: its `#:` comment} from the class's source (the lines above a field, or on it)."""
    src = inspect.getsource(cls)
    lines = src.splitlines()
    tree = ast.parse(src)
    out = {}
    for node in tree.body[0].body:
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            i = node.lineno - 1
            text = []
            if "#:" in lines[i]:
                text.append(lines[i].split("#:", 1)[1].strip())
            j = i - 1
            above = []
            while j >= 0 and lines[j].strip().startswith("#:"):
                above.insert(0, lines[j].strip()[2:].strip())
                j -= 1
            out[node.target.id] = " ".join(above + text)
    return out


def _type_name(t) -> str:
    origin, args = typing.get_origin(t), typing.get_args(t)
    if origin is typing.Union:
        alts = [a for a in args if a is not type(None)]
        if len(alts) < len(args) and len(alts) == 1:
            return f"{_type_name(alts[0])} or null"
        return " or ".join(f"!{a.__name__}" for a in alts)
    if origin is list:
        return f"list of {_type_name(args[0])}" if args else "list"
    return getattr(t, "__name__", str(t))


def _is_variant(t) -> bool:
    """Whether a field's type is a union of several dataclasses (a tagged variant)."""
    alts = [a for a in typing.get_args(t) if a is not type(None)]
    return len(alts) > 1 and all(dc.is_dataclass(a) for a in alts)


def _default(f, variant: bool) -> str:
    if f.default is not dc.MISSING:
        v = f.default
    elif f.default_factory is not dc.MISSING:
        v = f.default_factory()
    else:
        return ""
    if dc.is_dataclass(v):
        return f"`!{type(v).__name__}`" if variant else "(section)"
    if v is None:
        return "null"
    if isinstance(v, bool):
        return f"`{str(v).lower()}`"
    return f"`{v}`"


def _section(cls, path: str, out: list, seen: set, variant: bool) -> None:
    if cls in seen and path in seen:
        return
    doc = inspect.getdoc(cls) or ""
    tag = f" — `!{cls.__name__}`" if variant else ""
    out += [(f"### `{path}`" if path else "### The top level") + tag, ""]
    if doc:
        out += [" ".join(doc.split()), ""]
    hints = typing.get_type_hints(cls)
    comments = _field_comments(cls)
    rows, nested = [], []
    for f in dc.fields(cls):
        t = hints[f.name]
        var = _is_variant(t)
        rows.append(f"| `{f.name}` | {_type_name(t) if var or not dc.is_dataclass(t) else 'section'} | "
                    f"{_default(f, var)} | {comments.get(f.name, '')} |")
        alts = [a for a in typing.get_args(t) if a is not type(None)] or [t]
        for a in alts:
            if dc.is_dataclass(a):
                nested.append((a, f"{path}.{f.name}" if path else f.name, var))
    out += ["| field | type | default | meaning |", "| --- | --- | --- | --- |", *rows, ""]
    for a, p, var in nested:
        _section(a, p, out, seen, var)


def reference() -> str:
    """The text of docs/configuration.md."""
    out = ["# Configuration reference", "",
           "Written by `nbvs config-reference` from the schema in `nbvs_drake/config/schema.py`; do not edit",
           "by hand. A scenario is a YAML file of these sections (unknown keys are an error). Variants are",
           "tagged (`strategy: !Ort {vertices: 2000}`); an untagged mapping is the first variant listed. `null`",
           "means automatic or the preset's. On the command line, `--set section.field=value` takes a YAML",
           "value (`--set \"planner.evaluator=!Hrt {a: 2}\"`); a field of the current variant is set in place",
           "(`--set planner.evaluator.a=3`), and a leading `?` sets it only where the current variant has it.",
           "Scenarios and settings in the old flat schema (before the nested one) still load through the",
           "migration in `nbvs_drake/config/legacy.py`.", "",
           "## Presets", "",
           "A scenario starts from a preset with `preset: NAME`; its own sections are merged over the preset's.",
           "", "| preset | what it is |", "| --- | --- |"]
    for n in preset_names():
        text = (PRESETS_DIR / f"{n}.yaml").read_text().splitlines()
        doc = " ".join(x.lstrip("# ").strip() for x in text if x.startswith("#"))
        out.append(f"| `{n}` | {doc} |")
    out += ["", "## Sections", ""]
    _section(S.Scenario, "", out, set(), False)
    return "\n".join(out).rstrip() + "\n"


def write_reference(path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(reference())
    return path
