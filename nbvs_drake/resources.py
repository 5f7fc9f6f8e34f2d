"""Where the package's data lies: the robot and object models (`models/`: URDF, meshes,
Newell's teapot patches) and the built-in scenarios with their rendered wiring (`diagrams/`).

The repository keeps both folders at its top level; they are the source of truth. A wheel
(`pip install .`) ships them inside the package, as `nbvs_drake/models/` and
`nbvs_drake/diagrams/` (pyproject.toml maps the two folders there and takes every file in
them), and they are found with :mod:`importlib.resources`. An editable install
(`pip install -e .`, what `make setup` does) or a checkout on ``sys.path`` has no such folders
inside the package: there the repository's own folders beside the package are used, so a file
added to `models/` or `diagrams/` is seen at once, and `nbvs diagram --all` writes the wiring
into the repository.

Every path returned is a real file-system path (Drake's parser and the mesh readers need one).
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path

from .errors import NbvsError, ScenarioError

#: the built-in scenario used when none is given
DEFAULT_SCENARIO_NAME = "default"


def _shipped(name: str) -> Path | None:
    """The folder inside the installed package (a wheel install), else None."""
    p = importlib.resources.files(__package__) / name
    return p if isinstance(p, Path) and p.is_dir() else None


def _checkout_root() -> Path:
    return Path(__file__).resolve().parent.parent


def _data_dir(name: str) -> Path:
    shipped = _shipped(name)
    if shipped is not None:
        return shipped
    checkout = _checkout_root() / name
    if checkout.is_dir():  # an editable install or a checkout on sys.path
        return checkout
    shipped = importlib.resources.files(__package__) / name
    raise NbvsError(f"nbvs_drake's data folder {name}/ is missing (looked in {shipped} and {checkout}); "
                    "reinstall the package")


def models_dir() -> Path:
    """The folder of the robot and object models."""
    return _data_dir("models")


def diagrams_dir() -> Path:
    """The folder of the built-in scenarios (`<name>.yaml`) and their wiring pictures."""
    return _data_dir("diagrams")


def source_checkout() -> Path | None:
    """The repository's root when the data comes from a source checkout (editable install),
    else None (a wheel install)."""
    if _shipped("diagrams") is not None:
        return None
    root = _checkout_root()
    return root if (root / "diagrams").is_dir() else None


def model_path(name: str | Path) -> Path:
    """`name` relative to the models folder (an absolute path is returned as is). The file
    need not exist; callers say what is missing."""
    p = Path(name)
    return p if p.is_absolute() else models_dir() / p


def builtin_scenarios() -> dict[str, Path]:
    """The built-in scenarios: name (the file's stem) -> YAML path, sorted by name."""
    return {p.stem: p for p in sorted(diagrams_dir().glob("*.yaml"))}


def default_scenario_path() -> Path:
    return diagrams_dir() / f"{DEFAULT_SCENARIO_NAME}.yaml"


def scenario_path(name_or_path: str | Path | None = None) -> Path:
    """The YAML file of a scenario: None is the default scenario; an existing file is itself
    (a file wins over a built-in of the same name); else a built-in scenario's name, with or
    without `.yaml` (`teapot_eu_mu`). Anything else raises a one-line ScenarioError that lists
    the built-in names."""
    if name_or_path is None:
        return default_scenario_path()
    p = Path(name_or_path)
    if p.is_file():
        return p
    builtin = builtin_scenarios()
    text = str(name_or_path)
    if "/" not in text and "\\" not in text:
        stem = text[:-5] if text.endswith(".yaml") else text
        if stem in builtin:
            return builtin[stem]
    raise ScenarioError(f"scenario file not found: {p} (neither a file nor a built-in scenario; "
                        f"built-in: {', '.join(builtin) or 'none'})")
