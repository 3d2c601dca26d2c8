# Two commands for a fresh machine with Python 3.11+: `make demo` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# the suite in two processes (pytest-xdist): most of its time is waiting on simulated controllers, brokers and
# file transfers, and each test keeps to its own ports, schemas, topics and temporary directories
TEST_WORKERS ?= 2

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
	$(BIN)/python -m pytest -n $(TEST_WORKERS) --dist worksteal

lint: $(STAMP)
	$(BIN)/ruff check rgse_daemon simulators tests bench examples
	$(BIN)/lint-imports

bench: $(STAMP)
	@for b in bench/*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

# Mutation testing (issue #18, #31; README "Mutation testing"), not part of `make test`: mutmut's single-operator
# mutants, each run against the fast tests that guard the module (`-m "not slow"`; per mutant mutmut runs just the
# tests that reach the mutated function, fastest first, stopping at the first failure). Two families:
# * the mass pipeline -- pipeline/mass.py, uncertainty.py, inline.py, preprocess.py, calibration.py, selection.py,
#   thermal.py -- against tests/pipeline (~15 s in all); the default. MUTATE=all takes every module of pipeline/
#   (cog, inertia, excitation, study, envelope too: ~8000 mutants, several hours) and the safety check below.
# * the interlock's static check -- MUTATE=safety: safety/static.py, allowlist.py, inputs.py; MUTATE=krl:
#   krl/evaluate.py, abstract.py, values.py -- against tests/safety_static + tests/krl without their hypothesis tests
#   (test_property, test_differential, test_roundtrip: random programs, ~30 s per surviving mutant, and a kill by
#   chance is no reproducible kill; they still run in `make test`). The rest of safety/ (monitor.py, latch.py,
#   makesafe.py) is guarded by tests on the TCP simulator (tests/procedures, tests/faults: 15-60 s per mutant) and is
#   not mutated (docs/accuracy.md, "Mutation testing of the interlock's static check").
# Only the tests of the family being mutated are collected (PYTEST_ADDOPTS=--ignore=...), so mutmut's first full
# test run stays short.
# Narrow it with module names or paths: MUTATE="mass thermal" (pipeline names), MUTATE=krl/values or
# MUTATE=rgse_daemon/krl/evaluate.py. One worker by default (MUTATION_JOBS=2 for a machine of your own). The per-file
# score is printed at the end.
MASS_PIPELINE := mass uncertainty inline preprocess calibration selection thermal
SAFETY_CHECK := safety/static safety/allowlist safety/inputs krl/evaluate krl/abstract krl/values
MUTATE ?= $(MASS_PIPELINE)
MUTATION_JOBS ?= 1
# MUTATE's words as package paths (pipeline/mass, krl/values ...): "safety", "krl" name their groups; a bare name is
# a pipeline module.
MUTATE_PATHS = $(foreach m,$(MUTATE),$(if $(filter safety,$(m)),$(filter safety/%,$(SAFETY_CHECK)),$(if $(filter krl,$(m)),$(filter krl/%,$(SAFETY_CHECK)),$(if $(findstring /,$(m)),$(basename $(m:rgse_daemon/%=%)),pipeline/$(basename $(m))))))
MUTATE_RANDOM_TESTS := tests/safety_static/test_property.py tests/safety_static/test_differential.py \
	tests/krl/test_roundtrip.py
MUTATE_IGNORE = $(if $(filter all,$(MUTATE)),,$(if $(filter pipeline/%,$(MUTATE_PATHS)),,tests/pipeline) \
	$(if $(filter-out pipeline/%,$(MUTATE_PATHS)),$(MUTATE_RANDOM_TESTS),tests/safety_static tests/krl))
mutation: $(STAMP)
	rm -rf mutants
	PYTEST_ADDOPTS="$(strip $(foreach i,$(MUTATE_IGNORE),--ignore=$(i)))" $(BIN)/mutmut run --max-children $(MUTATION_JOBS) $(if $(filter all,$(MUTATE)),,$(foreach m,$(MUTATE_PATHS),"rgse_daemon.$(subst /,.,$(m)).*"))
	$(BIN)/mutmut results
	$(BIN)/python scripts/mutation_score.py $(if $(filter all,$(MUTATE)),,$(foreach m,$(MUTATE_PATHS),$(m).py))

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache mutants
