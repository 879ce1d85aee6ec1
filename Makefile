# piezopress: every target builds its own environment from nothing (.venv in the checkout).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
PP     := $(BIN)/piezopress
OUT    ?= out
RUNS   ?= sample_runs/characterization
BUILD  ?= build
# make refit STRUCTURE='n=8 gamma=2 m=4 plane=20': the hysteresis structure kept, not searched for
STRUCTURE ?=
STRUCTURE_OPT = $(if $(STRUCTURE),--structure '$(STRUCTURE)',)

SAMPLES ?= sample_runs
REPORT ?= report

.PHONY: demo test test-integration test-all lint bench clean help refit report sample-runs expected-metrics

help:
	@echo "make demo      build the environment; characterize, fit, validate, diagnose and report on the virtual rig"
	@echo "make test      build the environment and run the fast test suite (under 5 minutes on 2 cores)"
	@echo "make test-integration   the chains on whole presses and real data sets (CI runs them too)"
	@echo "make test-all  every test: the fast suite, the integration tests and the slow tests"
	@echo "make lint      ruff check (the rules in pyproject.toml; CI runs it)"
	@echo "make bench     run the benchmark scripts in bench/"
	@echo "make refit RUNS=dir   rebuild $(BUILD)/bundle.json from a run directory; only stages whose inputs changed"
	@echo "           STRUCTURE='n=8 gamma=2 m=4 plane=20' keeps that hysteresis structure instead of searching"
	@echo "make report    regenerate $(REPORT)/ from sample_runs/ (nothing to do when nothing changed)"
	@echo "make sample-runs SAMPLES=dir   record a new sample set from the virtual rig"

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

# The whole chain on the virtual rig, into a new dated directory (nothing is overwritten).
demo: $(STAMP)
	@$(PP) demo --out $(OUT)/demo-$$(date -u +%Y%m%dT%H%M%SZ)

# The tests on every core (pytest-xdist): a module's tests on one worker, so its fixtures are built
# once (--dist loadscope), and each worker's OpenMP on one thread (OpenBLAS's is one already:
# piezopress/__init__.py). TEST_WORKERS=0: one process, as plain pytest runs.
TEST_WORKERS ?= auto
PYTEST_XDIST = OMP_NUM_THREADS=1 $(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadscope
test: $(STAMP)
	$(PYTEST_XDIST)

# The chains on whole simulated presses and the real data sets (marked integration): CI runs them
# after the fast suite.
test-integration: $(STAMP)
	$(PYTEST_XDIST) -m 'integration and not slow'

lint: $(STAMP)
	$(BIN)/ruff check .

test-all: $(STAMP)
	$(BIN)/python -m pytest -q -m ''

# Each stage records a digest of its inputs (runs' sha256, upstream sections, options) and
# --if-changed skips it when they are unchanged, so a second `make refit` does nothing.
refit: $(STAMP)
	@mkdir -p $(BUILD)
	$(PP) fit-hysteresis $(RUNS) --out $(BUILD)/hysteresis-first.json --if-changed $(STRUCTURE_OPT)
	$(PP) fit-creep $(RUNS) --hysteresis $(BUILD)/hysteresis-first.json --out $(BUILD)/creep.json --if-changed
	$(PP) fit-hysteresis $(RUNS) --creep $(BUILD)/creep.json --out $(BUILD)/hysteresis.json --if-changed $(STRUCTURE_OPT)
	$(PP) fit-shaper $(RUNS) --out $(BUILD)/shaper.json --if-changed
	$(PP) bundle --hysteresis $(BUILD)/hysteresis.json --creep $(BUILD)/creep.json --shaper $(BUILD)/shaper.json --out $(BUILD)/bundle.json --if-changed

# Record the committed sample set again (into a new directory: SAMPLES=somewhere-new).
sample-runs: $(STAMP)
	@test ! -e $(SAMPLES)/characterization || { echo "$(SAMPLES)/ already holds runs: give SAMPLES=a-new-directory"; exit 1; }
	mkdir -p $(SAMPLES)
	cp rigs/thesis-press.toml $(SAMPLES)/rig.toml
	$(PP) characterize --rig $(SAMPLES)/rig.toml --out $(SAMPLES)/characterization
	$(PP) fit $(SAMPLES)/characterization --rig $(SAMPLES)/rig.toml --out $(SAMPLES)/bundle.json
	$(PP) validate --bundle $(SAMPLES)/bundle.json --rig $(SAMPLES)/rig.toml --out $(SAMPLES)/validation
	$(PP) fit $(SAMPLES)/characterization --base --rig $(SAMPLES)/rig.toml --out $(SAMPLES)/base-bundle.json
	$(PP) diagnose $(SAMPLES)/characterization --bundle $(SAMPLES)/base-bundle.json --out $(SAMPLES)/diagnosis

# The report from the committed sample runs; make's timestamps make a second run a no-op.
REPORT_INPUTS := $(shell find $(SAMPLES) -type f 2>/dev/null) $(shell find piezopress pipelines -name '*.py' 2>/dev/null)
report: $(REPORT)/metrics.csv

$(REPORT)/metrics.csv: $(REPORT_INPUTS) | $(STAMP)
	$(PP) report --characterization $(SAMPLES)/characterization --validation $(SAMPLES)/validation \
	    --bundle $(SAMPLES)/bundle.json --diagnosis $(SAMPLES)/diagnosis --out $(REPORT) --replace

# After a deliberate change of a metric: record the new expected table (review the diff).
expected-metrics: $(STAMP)
	$(BIN)/python -c "from piezopress.pipelines import report as R; R.expected_table(R.build_report('$(SAMPLES)/characterization', '$(SAMPLES)/validation', '$(SAMPLES)/bundle.json', '$(SAMPLES)/diagnosis')).to_csv('$(SAMPLES)/expected_metrics.csv', index=False, float_format='%.6g')"

bench: $(STAMP)
	@for f in bench/*.py; do echo "== $$f"; $(BIN)/python $$f || exit 1; done

clean:
	rm -rf $(VENV) .pytest_cache $(BUILD)
