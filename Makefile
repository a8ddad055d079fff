# Fresh machine: `make benchmark` (the main job) or `make test`.  Each builds .venv itself.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
export MUJOCO_GL ?= egl

.PHONY: venv test slow-test cluster-test research-test lint docs properties wheel-smoke benchmark benchmark-check speed learnability view clean

# The venv is rebuilt only when pyproject.toml changes (torch is a large download).
$(BIN)/activate: pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e ".[dev]"
	touch $(BIN)/activate

venv: $(BIN)/activate

test: venv
	$(BIN)/ruff check tendon2r_gym scripts tests research
	$(BIN)/python -m pytest -q -n auto -m "not cluster and not slow" tests research/tests
	$(MAKE) wheel-smoke

# Tests of minutes (a study's fits on two workers), kept out of make test's ten minutes.
slow-test: venv
	$(BIN)/python -m pytest -q -n auto -m slow tests research/tests

# The executors on a real two-node Ray cluster on 127.0.0.1 (one process: one cluster).
cluster-test: venv
	$(BIN)/python -m pytest -q -p no:xdist -m cluster tests/test_executors.py

# The docs site (MkDocs Material, strict: a broken link or a missing page fails); the
# generated pages and README's headline table first (tests/test_docs.py checks both, and
# builds the site in strict mode, in make test).
docs: venv
	$(BIN)/python scripts/gen_docs.py
	$(BIN)/mkdocs build --strict --site-dir build/site

# The research folder's own tests (make test runs them too).
research-test: venv
	$(BIN)/python -m pytest -q -n auto research/tests

# The property-based tests' long run (CI runs 25 draws per property; this runs 1000).
properties: venv
	HYPOTHESIS_PROFILE=long $(BIN)/python -m pytest -q tests/test_properties.py

lint: venv
	$(BIN)/ruff check tendon2r_gym scripts tests research

# Non-editable install: build the wheel, install it into a fresh venv that borrows the test
# venv's dependencies (no download), and use it from outside the checkout.
wheel-smoke: venv
	bash .ci/wheel_smoke.sh

benchmark: venv
	$(BIN)/tendon2r-benchmark

# Reruns the benchmark beside the committed one and compares every row within its
# reproducibility (scripts/compare_benchmarks.py).
benchmark-check: venv
	$(BIN)/tendon2r-benchmark --out runs/benchmark-check
	$(BIN)/python scripts/compare_benchmarks.py results/benchmark.json runs/benchmark-check/benchmark.json

speed: venv
	$(BIN)/python -m research.studies.speed
	$(BIN)/python -m research.studies.timestep

learnability: venv
	$(BIN)/python -m research.studies.learnability

view: venv
	$(BIN)/tendon2r-view --save results/default.png

clean:
	rm -rf $(VENV) runs build dist
