# Fresh machine: `make benchmark` (the main job) or `make test`.  Each builds .venv itself.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
export MUJOCO_GL ?= egl

.PHONY: venv test lint benchmark speed view clean

$(BIN)/activate: pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e ".[dev]"
	touch $(BIN)/activate

venv: $(BIN)/activate

test: venv
	$(BIN)/ruff check tendon2r_gym scripts tests
	$(BIN)/python -m pytest -q

lint: venv
	$(BIN)/ruff check tendon2r_gym scripts tests

benchmark: venv
	$(BIN)/python scripts/benchmark.py

speed: venv
	$(BIN)/python scripts/bench_speed.py
	$(BIN)/python scripts/timestep_study.py

view: venv
	$(BIN)/python scripts/view.py --save results/default.png

clean:
	rm -rf $(VENV) runs
