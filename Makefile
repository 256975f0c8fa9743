# biasgt: two commands, each doing its own set-up on a fresh machine.
#   make run   create .venv, install, run the whole workflow on the built-in default data
#   make test  create .venv, install, lint (ruff), run the full test suite
PYTHON ?= python3.11
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.biasgt-installed
CORES ?= 2

.PHONY: run test lint install bench clean

$(STAMP): pyproject.toml requirements.lock
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "need $(PYTHON) (set PYTHON=...)"; exit 1; }
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -r requirements.lock
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e .
	@touch $(STAMP)

install: $(STAMP)

run: $(STAMP)
	$(VENV)/bin/biasgt run --cores $(CORES)
	@test ! -f results/evaluation/table.md || cat results/evaluation/table.md

test: lint
	$(PY) -m pytest -q -n $(CORES) --dist loadgroup

lint: $(STAMP)
	$(PY) -m ruff check .

bench: $(STAMP)
	@for b in benchmarks/*/*.py; do echo "== $$b"; $(PY) $$b || exit 1; done

clean:
	rm -rf results logs .snakemake
