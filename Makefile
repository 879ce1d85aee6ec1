# piezopress: every target builds its own environment from nothing (.venv in the checkout).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
PP     := $(BIN)/piezopress
OUT    ?= out

.PHONY: demo test test-all bench clean help

help:
	@echo "make demo      build the environment and run the default characterization on the virtual rig"
	@echo "make test      build the environment and run the fast test suite"
	@echo "make test-all  also run the slow tests"
	@echo "make bench     run the benchmark scripts in bench/"

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	@mkdir -p $(OUT)
	$(PP) characterize --out $(OUT)/characterization-$$(date -u +%Y%m%dT%H%M%SZ)

test: $(STAMP)
	$(BIN)/python -m pytest -q

test-all: $(STAMP)
	$(BIN)/python -m pytest -q -m ''

bench: $(STAMP)
	@for f in bench/*.py; do echo "== $$f"; $(BIN)/python $$f || exit 1; done

clean:
	rm -rf $(VENV) .pytest_cache
