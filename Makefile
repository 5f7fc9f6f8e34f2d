# nbvs_drake: `make run` sets everything up and reconstructs the default scene;
# `make test` sets everything up and runs the test suite. Set-up happens once:
# `.venv/.installed` is rebuilt only when pyproject.toml changes.
PYTHON ?= python3
VENV := .venv
STAMP := $(VENV)/.installed
OUT ?= results/default

.PHONY: setup run test test-slow lint bench diagrams clean

setup: $(STAMP)

$(STAMP): pyproject.toml scripts/setup.sh
	PYTHON=$(PYTHON) bash scripts/setup.sh
	touch $(STAMP)

run: setup
	$(VENV)/bin/nbvs reconstruct --out $(OUT) --overwrite

test: setup
	$(VENV)/bin/python -m pytest -q -m "not slow" --durations=20

lint: setup
	$(VENV)/bin/ruff check nbvs_drake tests scripts benchmarks docs/examples

test-slow: setup
	$(VENV)/bin/python -m pytest -q -m slow

bench: setup
	$(VENV)/bin/python benchmarks/run_all.py

# the papers' experiments (nbvs_drake/experiments/definitions/): `make experiment NAME=motion_noise
# ARGS="--quick"` runs one into results/experiments/; `make results` assembles docs/results.md
.PHONY: experiment results
experiment: setup
	$(VENV)/bin/nbvs experiment $(NAME) $(ARGS)

results: setup
	$(VENV)/bin/nbvs experiment report

diagrams: setup
	$(VENV)/bin/nbvs diagram --all

clean:
	rm -rf $(VENV) results .pytest_cache
