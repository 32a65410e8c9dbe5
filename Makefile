# The two commands a fresh machine needs (see README):
#   make demo   -> end-to-end pipeline on the built-in hydraulic MuJoCo excavator (quick-hydraulic, <= 5 min)
#   make test   -> lint (ruff + the import-linter layer contract) + the whole test suite (what CI runs)
#
# Both work in a project virtual environment $(VENV) created with $(PY); nothing is installed into
# the system Python.  `make demo` installs the package alone (no extras); `make test` adds the dev
# extra.  Stamp files in $(VENV) skip the install while pyproject.toml is unchanged.
#
# torch: CPU build by default.  A torch already in $(VENV), or a wheel pip finds offline through
# its configured find-links, is used as is (no index is contacted for it); otherwise torch comes
# from $(TORCH_INDEX).  CUDA: make demo TORCH_INDEX=https://download.pytorch.org/whl/cu126
# (in a fresh $(VENV): rm -rf .venv first).  TORCH_INDEX= (empty): torch from PyPI like any
# other dependency (on Linux that is the CUDA build).
PY ?= python3
VENV ?= .venv
OUT ?= runs/quick
TORCH_INDEX ?= https://download.pytorch.org/whl/cpu
TORCH_SPEC ?= torch>=2.4,<2.14
DOCS_SITE ?= build/site
# Test processes (pytest-xdist): many tests already run two processes or threads, so 2 gives
# about 1.3-1.4x on a 2-core computer.  TEST_WORKERS=0: one process, as plain `pytest`.
TEST_WORKERS ?= 2

BIN := $(VENV)/bin
VPY := $(BIN)/python
PIP := $(VPY) -m pip
SRC := src tests bench examples

.PHONY: install install-dev demo test lint format docs bench

install: $(VENV)/.stamp-base
install-dev: $(VENV)/.stamp-dev

$(VPY):
	$(PY) -m venv $(VENV)

$(VENV)/.stamp-torch: | $(VPY)
	@if $(VPY) -c "import torch" 2>/dev/null; then \
		echo "torch: $$($(VPY) -c 'import torch; print(torch.__version__)') already in $(VENV)"; \
	elif $(PIP) install -q --no-index --no-deps --only-binary=:all: "$(TORCH_SPEC)" 2>/dev/null; then \
		echo "torch: installed from pip's find-links"; \
	elif [ -n "$(TORCH_INDEX)" ]; then \
		$(PIP) install --only-binary=:all: "$(TORCH_SPEC)" --index-url "$(TORCH_INDEX)"; \
	else \
		echo "torch: TORCH_INDEX is empty, torch comes from PyPI with the package"; \
	fi
	@touch $@

$(VENV)/.stamp-base: pyproject.toml $(VENV)/.stamp-torch
	$(PIP) install -q -e .
	@touch $@

$(VENV)/.stamp-dev: pyproject.toml $(VENV)/.stamp-torch
	$(PIP) install -q -e ".[dev]"
	@touch $@ $(VENV)/.stamp-base

demo: $(VENV)/.stamp-base
	$(VPY) -m excavator_surrogate run --out $(OUT)

test: $(VENV)/.stamp-dev
	$(BIN)/ruff check $(SRC)
	$(BIN)/lint-imports
	$(VPY) -m pytest -q -n $(TEST_WORKERS) --dist worksteal
	@$(MAKE) --no-print-directory docs

# The documentation site, when mkdocs.yml exists (built into $(DOCS_SITE), warnings are errors).
docs: $(VENV)/.stamp-dev
	@if [ -f mkdocs.yml ]; then \
		NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir $(DOCS_SITE); \
	else \
		echo "docs: no mkdocs.yml, site build skipped"; \
	fi

lint: $(VENV)/.stamp-dev
	$(BIN)/ruff check $(SRC)
	$(BIN)/ruff format --check $(SRC)
	$(BIN)/lint-imports

format: $(VENV)/.stamp-dev
	$(BIN)/ruff format $(SRC)
	$(BIN)/ruff check --fix $(SRC)

bench: $(VENV)/.stamp-dev
	for b in bench/*.py; do $(VPY) $$b || exit 1; done
