"""Counts the shape of the configuration (issue #47's measures): leaf fields (each variant's
once), booleans off by default that no built-in scenario or preset turns on but some
experiment level does, level `set:` entries that repeat an earlier level's of the same factor,
modules directly in nbvs_drake/, README lines. Prints JSON."""

import dataclasses as dc
import json
import typing
from pathlib import Path

import yaml

from nbvs_drake.config import load_scenario, preset_scenario, schema, settings_of
from nbvs_drake.config.load import preset_names
from nbvs_drake.experiments.definition import DEFINITIONS_DIR, expand, load_definition, resolve
from nbvs_drake.resources import builtin_scenarios

ROOT = Path(__file__).resolve().parents[1]


def leaves(cls, seen=None):
    """(dotted name, type, default) of every leaf field, each union alternative's once."""
    seen = set() if seen is None else seen
    out = []
    hints = typing.get_type_hints(cls)
    for f in dc.fields(cls):
        t = hints[f.name]
        alts = [a for a in typing.get_args(t) if a is not type(None)] or [t]
        subs = [a for a in alts if dc.is_dataclass(a)]
        if subs:
            for a in subs:
                if a not in seen:
                    seen.add(a)
                    out += [(f"{f.name}.{n}", tt, d) for n, tt, d in leaves(a, seen)]
        else:
            d = f.default if f.default is not dc.MISSING else (f.default_factory() if f.default_factory
                                                                is not dc.MISSING else None)
            out.append((f.name, t, d))
    return out


def main():
    fields = leaves(schema.Scenario)
    bools_off = [n for n, t, d in fields if t is bool and d is False]
    on_somewhere = set()
    for sc in [load_scenario(n) for n in builtin_scenarios()] + [preset_scenario(p) for p in preset_names()]:
        on_somewhere |= {k for k, v in settings_of(sc).items() if v is True}
    on_in_levels = set()
    for name in [p.stem for p in DEFINITIONS_DIR.glob("*.yaml")]:
        for r in expand(resolve(load_definition(name))):
            on_in_levels |= {k for k, v in settings_of(r.resolve()).items() if v is True}

    def leaf(k):
        return k.rsplit(".", 1)[-1]
    level_only = sorted(b for b in bools_off if not any(leaf(k) == leaf(b) for k in on_somewhere)
                        and any(leaf(k) == leaf(b) for k in on_in_levels))
    repeats, total = 0, 0
    for p in DEFINITIONS_DIR.glob("*.yaml"):
        d = yaml.safe_load(p.read_text())
        for f in d.get("factors") or []:
            earlier = set()
            for lv in f["levels"]:
                own = [str(x).replace(" ", "") for x in lv.get("set") or []]
                total += len(own)
                repeats += sum(1 for x in own if x in earlier)
                earlier |= set(own)
    print(json.dumps({
        "leaf_fields": len(fields),
        "booleans_off_by_default": len(bools_off),
        "booleans_on_only_in_experiment_levels": level_only,
        "definitions": len(list(DEFINITIONS_DIR.glob("*.yaml"))),
        "level_set_entries": total,
        "level_set_entries_repeating_an_earlier_level": repeats,
        "modules_directly_in_nbvs_drake": len(list((ROOT / "nbvs_drake").glob("*.py"))),
        "readme_lines": len((ROOT / "README.md").read_text().splitlines()),
    }, indent=1))


if __name__ == "__main__":
    main()
