# Two commands do everything: `make demo` and `make test`. Each creates or refreshes .venv itself.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
PYTEST_WORKERS ?= 2

.PHONY: demo test lint bench clean

$(VENV)/.stamp-runtime: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e .
	touch $@

$(VENV)/.stamp-dev: pyproject.toml $(VENV)/.stamp-runtime
	$(PY) -m pip install --quiet -e ".[dev]"
	$(PY) -m ipykernel install --sys-prefix --name python3 > /dev/null
	touch $@

demo: $(VENV)/.stamp-runtime
	$(VENV)/bin/jaxflex demo --out demo-output --overwrite

lint: $(VENV)/.stamp-dev
	$(PY) -m ruff check jaxflex tests benchmarks

# The test workers already fill the cores: one JAX CPU device per worker (see jaxflex.parallel).
# Workers, notebook kernels and subprocesses share compiled programs through JAX's on-disk
# cache (measured: the suite from a fresh clone 474 s without it, 413 s with it).
test: $(VENV)/.stamp-dev lint
	JAXFLEX_HOST_DEVICES=1 JAX_COMPILATION_CACHE_DIR=$(abspath $(VENV))/jax-cache \
	JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=0.2 \
	$(PY) -m pytest -n $(PYTEST_WORKERS) -m "not slow" tests

bench: $(VENV)/.stamp-dev
	$(PY) benchmarks/simulate.py
	$(PY) benchmarks/profile_simulate.py
	$(PY) benchmarks/identify.py
	$(PY) benchmarks/design.py
	$(PY) benchmarks/discover.py

clean:
	rm -rf $(VENV) demo-output .pytest_cache .ruff_cache
