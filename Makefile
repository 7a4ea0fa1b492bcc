# Set-up and entry points. `make demo` and `make test` do the whole set-up on
# a fresh machine: a .venv with Python >= 3.12 (found by scripts/find-python)
# and the package with every dependency from PyPI, at the versions pinned in
# constraints.txt (the ones the suite last passed with; `make lock` refreshes it).
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
PYTEST_ARGS ?=
# Two pytest workers (pytest-xdist), one per core; a test file stays on one worker, so its
# module fixtures are built once, and the files measured longest (tests/durations.json)
# go first so that the workers end together (tests/conftest.py). `make test XDIST=` runs
# in one process.
# A worker waits for a form the other is compiling (artifem.jit: up to 5 minutes instead of
# DOLFINx's 10 s).
XDIST  ?= -n 2 --dist loadfile --no-loadscope-reorder
# One BLAS/OpenMP thread per worker: two workers on two cores, each with OpenBLAS's
# default of a thread per core, fight for the cores in every dense product (measured:
# 8 % longer on the reduced-model tests). `make test XDIST= THREADS=2` for one process.
THREADS ?= 1

.PHONY: demo test lint docs test-durations test-wheel bench lock venv clean

venv: $(STAMP)

$(STAMP): pyproject.toml constraints.txt
	@python=$${PYTHON:-$$(scripts/find-python)} || exit 1; \
	  echo "using $$python ($$($$python --version))"; \
	  [ -x $(PY) ] || $$python -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -c constraints.txt -e ".[test]"
	@touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/artifem demo --out results/demo

# The whole suite, the long tests included (marked `slow`: every test of a file measured
# to take over 15 s in tests/durations.json, and the long studies marked by hand;
# `pytest --collect-only -q -m slow` lists them). To skip those while developing (2.5
# minutes with a warm JIT cache):
#   make test PYTEST_ARGS='-m "not slow"'
# Any other pytest arguments go the same way, e.g. PYTEST_ARGS='tests/test_airway.py -x'.
# Tests run in random order (pytest-randomly, seed printed first); replay one with
#   make test PYTEST_ARGS='--randomly-seed=N'   or keep the file order: '-p no:randomly'.
test: $(STAMP)
	OPENBLAS_NUM_THREADS=$(THREADS) OMP_NUM_THREADS=$(THREADS) $(PY) -m pytest $(XDIST) $(PYTEST_ARGS)

# The linter and the formatter (ruff, configured in pyproject.toml), as CI runs them:
# `$(VENV)/bin/ruff format .` lays a change out, `ruff check --fix .` fixes what it can.
lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

# The documentation site (Sphinx, MyST, autodoc, sphinx-gallery: docs/conf.py) into
# docs/_build/html; warnings are errors, so a broken reference or a failing demo fails it.
docs: $(STAMP)
	$(PY) -m pip install --quiet -c constraints.txt -e ".[docs]"
	cd docs && OPENBLAS_NUM_THREADS=$(THREADS) ../$(PY) -m sphinx -W --keep-going -b html . _build/html

# Refresh tests/durations.json, the seconds of each test file that order the files for
# the workers: the suite run with an empty JIT cache, as on a fresh machine; the file is
# rewritten only if the run passed.
test-durations: $(STAMP)
	cache=$$(mktemp -d) && XDG_CACHE_HOME=$$cache $(MAKE) test \
	  PYTEST_ARGS='--write-durations tests/durations.json $(PYTEST_ARGS)'; \
	  status=$$?; rm -rf $$cache; exit $$status

# The wheel a user installs: built from this tree, installed with its pinned
# dependencies into a fresh venv outside the source tree, and run there.
test-wheel: $(STAMP)
	scripts/test-wheel $(PY)

bench: $(STAMP)
	$(VENV)/bin/artifem bench fom --out results/bench_fom.json

# Refresh constraints.txt: the newest release of every dependency in a scratch
# venv, the whole suite run there, and the file rewritten only if it passed.
lock:
	scripts/lock

clean:
	rm -rf $(VENV) results .pytest_cache dist
