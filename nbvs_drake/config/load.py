"""Loading a scenario: a YAML file (or a built-in scenario's name) merged over its preset, then
dotted settings, then the kind's defaults, then the checks. A scenario in the old flat schema
(a record's, a user's) loads through `legacy.migrate`; an old dotted setting too."""

from __future__ import annotations

import copy
import dataclasses as dc
import typing
from pathlib import Path

from ..errors import ScenarioError
from . import legacy
from .schema import Scenario, SensorConfig

PRESETS_DIR = Path(__file__).resolve().parent / "presets"


def preset_names() -> list[str]:
    return sorted(p.stem for p in PRESETS_DIR.glob("*.yaml"))


def _preset_text(name: str) -> str:
    f = PRESETS_DIR / f"{name}.yaml"
    if not f.is_file():
        raise ScenarioError(f"unknown preset {name!r}; presets: {', '.join(preset_names())}")
    return f.read_text()


def _raw(text: str, what: str):
    import yaml
    try:
        return yaml.load(text, Loader=_TagIgnoringLoader) or {}
    except yaml.YAMLError as e:
        raise ScenarioError(f"malformed scenario {what}: {' '.join(str(e).split())}") from None


def _typed(text: str, defaults, what: str):
    from pydrake.common.yaml import yaml_load_typed
    try:
        return yaml_load_typed(schema=Scenario, data=text, defaults=defaults)
    except Exception as e:  # noqa: BLE001 - yaml_load_typed raises RuntimeError / yaml errors
        raise ScenarioError(f"malformed scenario {what}: {' '.join(str(e).split())}") from None


def preset_scenario(name: str, _seen=()) -> Scenario:
    """The scenario a preset describes (its own `preset:` first, then its sections)."""
    if name in _seen:
        raise ScenarioError(f"preset {name!r} starts from itself")
    text = _preset_text(name)
    base = _raw(text, f"preset {name}").get("preset")
    start = preset_scenario(base, _seen + (name,)) if base else Scenario()
    sc = _typed(text, start, f"preset {name}")
    sc.preset = name
    return sc


#: the sections a run's scenario.yaml writes: a document with all of them is written whole
WHOLE_SECTIONS = ("robot", "scene", "sensor", "noise", "mapper", "localisation", "planner", "mission")


def scenario_from_text(text: str, what: str = "", preset: str | None = None) -> Scenario:
    """A scenario YAML document: today's schema (over its `preset:`, or over `preset` when
    given), or the old flat one."""
    doc = _raw(text, what)
    if not isinstance(doc, dict):
        raise ScenarioError(f"malformed scenario {what}: not a mapping")
    if legacy.is_old_document(doc):
        try:
            return legacy.migrate(text)
        except ScenarioError:
            raise
        except Exception as e:  # noqa: BLE001
            raise ScenarioError(f"malformed scenario {what} (old schema): {' '.join(str(e).split())}") from None
    text = legacy.drop_removed_fields(text, doc, what)
    named = doc.get("preset")
    preset = preset or named
    # a scenario written whole (a run's scenario.yaml) over its own preset names every value
    # the preset gave it: a field it does not name was added since, and keeps the default the
    # schema gives it, the behaviour before the field existed (a preset's later "on" would
    # change what a record re-runs)
    whole = preset == named and all(k in doc for k in WHOLE_SECTIONS)
    start = preset_scenario(str(preset)) if preset and not whole else Scenario()
    sc = _typed(text, start, what)
    sc.preset = str(preset) if preset else None
    if whole:
        _keep_old_sensor_model(doc, sc)
    return sc


def _keep_old_sensor_model(doc: dict, sc: Scenario) -> None:
    """A scenario written whole before sensor.refine_multiple existed (a run's scenario.yaml
    or record that does not name it; the sensor's own presets are a second layer the schema's
    defaults do not reach) keeps what every sensor did then: top_k views scored again at the
    fine model (refine_multiple 1; the Kinect preset's since: 2)."""
    sensor = doc.get("sensor")
    if not (isinstance(sensor, dict) and "refine_multiple" in sensor):
        sc.sensor.refine_multiple = 1


def load_scenario(path=None, *, seed=None, settings=()) -> Scenario:
    """Loads and checks a scenario: `path` is a YAML file, a built-in scenario's name
    (``"teapot_eu_mu"``) or None (the default scenario). `settings`: "section.field=value"
    overrides (YAML values: "noise.sigma_w=0.14", "planner.evaluator=!Hrt {a: 2}"), applied in
    order; "preset=NAME" (the last one) first: the file's sections over that preset instead of
    its own (`--set preset=real_robot_paper`: the same scene with the paper's planner)."""
    from ..resources import scenario_path
    path = scenario_path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise ScenarioError(f"cannot read scenario file {path}: {e.strerror}") from None
    presets = [s.partition("=")[2].strip() for s in settings if s.partition("=")[0].strip() == "preset"]
    settings = [s for s in settings if s.partition("=")[0].strip() != "preset"]
    scenario = scenario_from_text(text, path.name, preset=presets[-1] if presets else None)
    if not scenario.base_dir:
        scenario.base_dir = str(path.resolve().parent)
    if seed is not None:
        scenario.seed = int(seed)
    kind = scenario.scene.object.kind
    for setting in settings:
        scenario = apply_setting(scenario, setting)
    _kind_defaults(scenario, kind, settings)
    return scenario.check()


def _kind_defaults(scenario: Scenario, file_kind: str, settings) -> None:
    """A scenario file's `size` and `up` belong to its own kind: when the settings change
    `scene.object.kind` and set no size (scale, up), the new kind's defaults apply
    (`--set scene.object.kind=bunny` gives the papers' 0.467 m bunny)."""
    o = scenario.scene.object
    if o.kind == file_kind:
        return
    keys = {s.lstrip("?").partition("=")[0].replace(" ", "") for s in settings}
    if not keys & {"scene.object.size", "scene.object.scale"}:
        o.size, o.scale = None, None
    if "scene.object.up" not in keys:
        o.up = None


def _field_type(cls, name):
    hints = typing.get_type_hints(cls)
    return hints.get(name)


def _walk_setting(scenario: Scenario, parts: list[str]):
    """Walks a dotted path through the scenario's current values. Returns (tags, None) when it
    reaches a field: for each key but the last, the tag its mapping needs so that the setting
    merges into the current variant ("!Hrt" when planner.evaluator is an Hrt) or None. Returns
    (None, (path, variant, key)) when it names a field that the current variant at `path`
    lacks, and (None, None) when it leaves the schema or enters an unset optional section."""
    tags, obj = [], scenario
    for i, k in enumerate(parts[:-1]):
        if not dc.is_dataclass(obj) or not any(f.name == k for f in dc.fields(obj)):
            return None, None
        alts = [a for a in typing.get_args(_field_type(type(obj), k)) if a is not type(None)]
        obj = getattr(obj, k)
        if obj is None:
            return None, None
        variant = len(alts) > 1
        if variant and dc.is_dataclass(obj) and not any(f.name == parts[i + 1] for f in dc.fields(obj)):
            return None, (".".join(parts[:i + 1]), type(obj).__name__, parts[i + 1])
        tags.append("!" + type(obj).__name__ if variant and type(obj) is not alts[0] else None)
    if not dc.is_dataclass(obj) or not any(f.name == parts[-1] for f in dc.fields(obj)):
        return None, None
    return tags, None


def _setting_text(parts: list[str], value: str, tags=None) -> str:
    """The YAML document of one dotted setting, each mapping with its tag (or none)."""
    tags = tags or [None] * (len(parts) - 1)
    text = "".join(f"{'  ' * i}{k}:{' ' + t if t else ''}\n" for i, (k, t) in enumerate(zip(parts[:-1], tags)))
    return text + f"{'  ' * (len(parts) - 1)}{parts[-1]}: {value}\n"


def apply_setting(scenario: Scenario, setting: str) -> Scenario:
    """A copy of `scenario` with one "dotted.key=value" setting applied (the value is YAML, a
    tag picks a variant: "planner.utility=!Expected {samples: 100}"), read through the same
    typed schema as a file: unknown keys and wrong types are refused naming the setting. A
    field of the current variant is set in place ("planner.evaluator.a=2" keeps the Hrt). A
    leading "?" applies the setting only where the field exists in the current variant
    ("?planner.utility.samples=20": only under the expected utility). An old flat key
    ("planner.hrt_a=2") is migrated (config/legacy.py)."""
    optional = setting.startswith("?")
    body = setting[1:] if optional else setting
    key, sep, value = body.partition("=")
    parts = [k.strip() for k in key.split(".")]
    value = value.strip()
    if not sep or not all(parts) or not value or "\n" in value:
        raise ScenarioError(f"setting {setting!r}: expected section.field=value, e.g. noise.sigma_w=0.14")
    if legacy.is_old_setting(".".join(parts), value):
        return _apply_old_setting(scenario, parts, value, setting)
    tags, other = _walk_setting(scenario, parts)
    if tags is None:
        if optional:
            return scenario
        if other is not None:  # an untagged mapping would silently switch to the first variant
            where, variant, key = other
            raise ScenarioError(f"setting {setting!r}: {where} is !{variant}, which has no field {key!r} "
                                f"(choose the variant: {where}=!Name {{...}})")
    from pydrake.common.yaml import yaml_load_typed
    try:
        out = yaml_load_typed(schema=Scenario, data=_setting_text(parts, value, tags), defaults=scenario)
    except Exception as e:  # noqa: BLE001 - yaml_load_typed raises RuntimeError / ValueError / TypeError
        raise ScenarioError(f"setting {setting!r}: {' '.join(str(e).split())}") from None
    out.preset = scenario.preset
    return out


def _apply_old_setting(scenario: Scenario, parts, value, setting) -> Scenario:
    try:
        old = legacy.load_old_text(_setting_text(parts, value), legacy.to_old(scenario))
    except Exception as e:  # noqa: BLE001
        raise ScenarioError(f"setting {setting!r}: {' '.join(str(e).split())}") from None
    # only what the setting changed: the fields the old schema cannot say (the registration's
    # search, the real-robot scenes) keep their values
    out = _with_changes(copy.deepcopy(scenario), legacy.from_old(legacy.to_old(scenario)), legacy.from_old(old))
    out.preset = scenario.preset
    return out


def _with_changes(target, before, after):
    """target with every field where `after` differs from `before` set to after's (nested
    sections field by field)."""
    for f in dc.fields(after):
        a, b = getattr(after, f.name), getattr(before, f.name)
        if a == b:
            continue
        t = getattr(target, f.name)
        if dc.is_dataclass(a) and type(a) is type(b) and type(t) is type(a):
            _with_changes(t, b, a)
        else:
            setattr(target, f.name, copy.deepcopy(a))
    return target


def validate(sc: Scenario) -> Scenario:
    """Raises ScenarioError naming the first impossible value (its nested path)."""
    return sc.check()


def resolve_sensor(sensor: SensorConfig) -> SensorConfig:
    """A copy with every preset-derived field filled in."""
    return sensor.resolved()


def with_resolved_sensor(sc: Scenario) -> Scenario:
    """A copy of sc whose sensor names every value (its preset's filled in): what a run's
    scenario.yaml records, so that a later change to a sensor preset does not change what a
    record's scenario re-runs."""
    sc = copy.copy(sc)
    sc.sensor = sc.sensor.resolved()
    return sc


def settings_of(sc) -> dict:
    """A scenario's settings as {dotted name: value}, a variant's tag under its own name
    ("planner.evaluator": "Hrt"), an unset optional section as None, the sensor's preset
    resolved (`with_resolved_sensor`); `base_dir` (the checkout) and `preset` (where the
    values came from) left out: two runs with equal settings are the same run."""
    sc = with_resolved_sensor(sc)
    out = {}

    def walk(obj, pre):
        for f in dc.fields(obj):
            v = getattr(obj, f.name)
            name = pre + f.name
            if dc.is_dataclass(v):
                args = [a for a in typing.get_args(_field_type(type(obj), f.name)) if a is not type(None)]
                if len(args) > 1:
                    out[name] = type(v).__name__
                walk(v, name + ".")
            else:
                out[name] = v
    walk(sc, "")
    out.pop("base_dir", None)
    out.pop("preset", None)
    return out


class _TagIgnoringLoader:
    """A yaml SafeLoader that reads tagged nodes (``!Ort {...}``) as plain values (for peeking
    at a document's keys)."""

    def __new__(cls, stream):
        import yaml

        class L(yaml.SafeLoader):
            pass

        def any_tag(loader, suffix, node):
            if isinstance(node, yaml.MappingNode):
                return loader.construct_mapping(node)
            if isinstance(node, yaml.SequenceNode):
                return loader.construct_sequence(node)
            return loader.construct_scalar(node)
        L.add_multi_constructor("!", any_tag)
        return L(stream)
