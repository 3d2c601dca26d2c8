# Two commands for a fresh machine with Python 3.11+: `make demo` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test lint bench venv clean mutation

venv: $(STAMP)

$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "Python >= 3.11 is needed, found " + sys.version.split()[0])'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/rgse demo $(if $(CONSOLE),--console $(CONSOLE))

test: $(STAMP)
	$(BIN)/ruff check rgse_daemon simulators tests bench examples
	$(BIN)/lint-imports
	bash scripts/ensure-services.sh
	$(BIN)/python -m pytest

lint: $(STAMP)
	$(BIN)/ruff check rgse_daemon simulators tests bench examples
	$(BIN)/lint-imports

bench: $(STAMP)
	@for b in bench/*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

# mutation testing of rgse_daemon/pipeline/ against the fast pipeline tests (slow: not part of `make test`);
# MUTATE=rgse_daemon/pipeline/mass.py narrows it to one file
mutation: $(STAMP)
	rm -rf mutants
	$(BIN)/mutmut run $(if $(MUTATE),"$(subst rgse_daemon/,rgse_daemon.,$(basename $(MUTATE)))*")
	$(BIN)/mutmut results

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache mutants
