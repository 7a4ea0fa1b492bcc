# Set-up and entry points. `make demo` and `make test` do the whole set-up on
# a fresh machine: a .venv with Python >= 3.12 (found by scripts/find-python)
# and the package with every dependency from PyPI.
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
PYTEST_ARGS ?=

.PHONY: demo test bench venv clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	@python=$${PYTHON:-$$(scripts/find-python)} || exit 1; \
	  echo "using $$python ($$($$python --version))"; \
	  [ -x $(PY) ] || $$python -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[test]"
	@touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/artifem demo --out results/demo

test: $(STAMP)
	$(PY) -m pytest $(PYTEST_ARGS)

bench: $(STAMP)
	$(VENV)/bin/artifem bench fom --out results/bench_fom.json

clean:
	rm -rf $(VENV) results .pytest_cache
