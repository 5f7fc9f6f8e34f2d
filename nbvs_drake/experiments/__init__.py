"""The papers' experiments as data: each definition (`definitions/*.yaml`) names a base
scenario, the factors varied (levels as `--set` overrides), the seeds, what to aggregate
and the published values; `nbvs experiment NAME` runs what is missing of it (locally or on
Ray), keeping every finished run, and writes its table and figures.

    from nbvs_drake.experiments import load_table
    t = load_table("results/experiments/motion_noise")
    t.cell("teapot/EU-MU/paper")["metrics"]["coverage"]["mean"]
"""

from .aggregate import Table, comparable, compared_markdown, load_table, write_table
from .definition import (
                         DEFINITIONS_DIR,
                         ExperimentError,
                         RunSpec,
                         definition_names,
                         expand,
                         load_definition,
                         resolve,
                         with_objects,
)
from .report import listing, write_report
from .runner import run_experiment

__all__ = ["DEFINITIONS_DIR", "ExperimentError", "RunSpec", "Table", "comparable", "compared_markdown",
           "definition_names", "expand", "listing", "load_definition", "load_table", "resolve", "run_experiment",
           "with_objects", "write_report", "write_table"]
