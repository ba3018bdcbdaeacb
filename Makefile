# The two commands of the README: `make demo` and `make test`. Both create the virtual
# environment when it is missing (or when pyproject.toml changed) and install into it.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test lint format bench install clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	# The CPU build of torch first: an unpinned torch would pull a multi-GB CUDA build.
	$(BIN)/python -m pip install --quiet torch==2.13.0
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	# numba compiles the rasterizer once per install (~40 s); here, not in the demo's loop.
	$(BIN)/aes-planner warmup
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/aes-planner demo

test: $(STAMP)
	$(BIN)/python -m pytest -q

# Format, lint and import-contract checks (CI runs them beside the tests); `make format` rewrites the tree.
lint: $(STAMP)
	$(BIN)/ruff format --check .
	$(BIN)/ruff check .
	# the floors of docs/architecture.md (import-linter contracts in pyproject.toml)
	$(BIN)/python .ci/lint_imports.py

format: $(STAMP)
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

# Benchmarks (JSON figures), then the checks too slow for `make test` (marked `slow`;
# pytest's exit status 5 means none are collected, which is fine).
bench: $(STAMP)
	mkdir -p bench
	$(BIN)/aes-planner bench --json bench/latest.json
	$(BIN)/python -m pytest -q -m slow || [ $$? -eq 5 ]

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis
