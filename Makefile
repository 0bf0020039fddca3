# geofix: two commands on a fresh machine -- `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
OUT    ?= out/demo

.PHONY: demo test lint format results bench docs clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e ".[dev]"
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/geofix demo --out $(OUT)

test: $(STAMP)
	$(BIN)/ruff check src tests benchmarks examples docs/conf.py
	$(BIN)/ruff format --check src tests benchmarks examples docs/conf.py
	$(BIN)/mypy
	$(BIN)/pytest -q -n 2 --dist loadfile -m "not serial"
	$(BIN)/pytest -q -m serial

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks examples docs/conf.py

format: $(STAMP)
	$(BIN)/ruff format src tests benchmarks examples docs/conf.py
	$(BIN)/ruff check --fix src tests benchmarks examples docs/conf.py

results: $(STAMP)
	$(BIN)/python benchmarks/results.py --out docs/RESULTS.md

# The pytest-benchmark suite (benchmarks/bench_*.py); writes the performance section of
# docs/RESULTS.md. NUMBA_NUM_THREADS=2 lets the threading figure use both cores.
$(VENV)/.bench-installed: $(STAMP)
	$(BIN)/pip install --quiet -e ".[dev,bench]"
	touch $@

bench: $(VENV)/.bench-installed
	NUMBA_NUM_THREADS=2 $(BIN)/python benchmarks/results.py --out docs/RESULTS.md --only performance

# The documentation site, offline, warnings as errors: docs/_build/html/index.html.
docs: $(STAMP)
	$(BIN)/pip install --quiet -e ".[docs]"
	MPLBACKEND=Agg NUMBA_NUM_THREADS=1 $(BIN)/sphinx-build -b html -W --keep-going -q docs docs/_build/html

clean:
	rm -rf $(VENV) out .pytest_cache .ruff_cache docs/_build docs/api/generated docs/auto_examples
