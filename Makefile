# Two commands do everything: `make demo` and `make test`. Each creates or refreshes .venv itself.
# `make docs` builds the documentation site into site/; `make notebooks` re-executes the notebooks.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
PYTEST_WORKERS ?= 2

# The public real-rig measurements: tests and notebooks read them from a local folder laid out
# like the upstream registry (checked against the same hashes) when one sits beside the project;
# without it, the tests that need them skip and say why (jaxflex.datasets).
REALDATA ?= $(abspath ../shared/realdata)
DATA_ENV := $(if $(wildcard $(REALDATA)/README.md),JAXFLEX_DATA_DIR=$(REALDATA),)

# The test suite's environment, shared by the notebooks: one JAX CPU device per process (the
# workers already fill the cores; see jaxflex.parallel), compiled programs shared through JAX's
# on-disk cache, no progress bars.
TEST_ENV := JAXFLEX_HOST_DEVICES=1 JAX_COMPILATION_CACHE_DIR=$(abspath $(VENV))/jax-cache \
	JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=0 JAXFLEX_PROGRESS=0 $(DATA_ENV)

.PHONY: demo test lint docs notebooks bench clean

$(VENV)/.stamp-runtime: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e .
	touch $@

$(VENV)/.stamp-dev: pyproject.toml $(VENV)/.stamp-runtime
	$(PY) -m pip install --quiet -e ".[dev,docs]"
	$(PY) -m ipykernel install --sys-prefix --name python3 > /dev/null
	touch $@

demo: $(VENV)/.stamp-runtime
	$(VENV)/bin/jaxflex demo --out demo-output --overwrite

lint: $(VENV)/.stamp-dev
	$(PY) -m ruff check jaxflex tests benchmarks notebooks/execute.py docs

# Workers, notebook kernels and subprocesses share compiled programs through JAX's on-disk
# cache. The strict documentation build runs first: a broken reference fails the tests.
test: $(VENV)/.stamp-dev lint docs
	$(TEST_ENV) $(PY) -m pytest -n $(PYTEST_WORKERS) --dist worksteal -m "not slow" --durations=15 tests

# Strict: any warning (an unresolved reference, a docstring mkdocstrings cannot read, a page
# missing from the navigation, a public name missing from the API reference) fails the build.
# Not --quiet: it hides the warnings from strict mode's count, and the build would pass.
docs: $(VENV)/.stamp-dev
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict

# Executes every notebook in place with the test suite's environment (full budgets), so that
# they are committed with their outputs and figures.
notebooks: $(VENV)/.stamp-dev
	$(TEST_ENV) MPLBACKEND=Agg $(PY) notebooks/execute.py notebooks/*.ipynb

bench: $(VENV)/.stamp-dev
	$(PY) benchmarks/simulate.py
	$(PY) benchmarks/profile_simulate.py
	$(PY) benchmarks/substeps.py
	$(PY) benchmarks/scaling.py
	$(PY) benchmarks/identify.py
	$(PY) benchmarks/design.py
	$(PY) benchmarks/discover.py
	$(DATA_ENV) $(PY) benchmarks/real_rig.py

clean:
	rm -rf $(VENV) demo-output site .pytest_cache .ruff_cache
