# The two commands a fresh machine needs (see README):
#   make demo   -> end-to-end pipeline on the built-in hydraulic MuJoCo excavator (quick-hydraulic, <= 5 min)
#   make test   -> lint (ruff + the import-linter layer contract) + the whole test suite (what CI runs)
PY ?= python3
OUT ?= runs/quick

.PHONY: install demo test lint format bench

install:
	$(PY) -m pip install -q -e ".[dev]"

demo: install
	$(PY) -m excavator_surrogate run --out $(OUT)

test: install
	$(PY) -m ruff check src tests bench examples
	lint-imports
	$(PY) -m pytest -q

lint:
	$(PY) -m ruff check src tests bench examples
	$(PY) -m ruff format --check src tests bench examples
	lint-imports

format:
	$(PY) -m ruff format src tests bench examples
	$(PY) -m ruff check --fix src tests bench examples

bench:
	for b in bench/*.py; do $(PY) $$b || exit 1; done
