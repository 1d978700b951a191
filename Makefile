PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: install test lint samples bench accuracy clean

install: $(BIN)/dynslam

$(BIN)/dynslam: pyproject.toml setup.py $(wildcard dynslam_cli/*/*.pyx)
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'
	$(BIN)/python -m compileall -q dynslam_cli formats  # bytecode now, not at every start
	@touch $@

test: install
	$(BIN)/pytest -q

lint: install
	$(BIN)/ruff check .

# The bundled sample logs, made by the simulator with fixed seeds (deterministic).
samples: install
	$(BIN)/dynslam simulate hall -o samples/hall --duration 90 --rate 5 --seed 1 --force
	$(BIN)/dynslam simulate corridors -o samples/corridors --duration 160 --rate 4 --seed 2 --force

# Speed and memory of the real pipeline (not part of the tests): bench/results.json.
bench: install
	$(BIN)/python bench/run.py --runs 5

# Accuracy of every built-in world, with and without the paper's components, and of the
# Radish corrected logs under drifting odometry of our own (perfect, moderate, harsh).
accuracy: install
	$(BIN)/python bench/accuracy.py
	$(BIN)/python bench/radish.py

clean:
	rm -rf $(VENV) *.egg-info .pytest_cache .ruff_cache
