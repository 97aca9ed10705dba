# Two entry points for a fresh clone (see README): `make demo` and `make test`.
# Both create the virtual environment first if it is missing or out of date.
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
OUT    ?= out/demo

.PHONY: demo methods test lint bench venv clean

venv: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	touch $@

# The whole chain headless on the default scenario (a real human demonstration).
demo: venv
	$(BIN)/telesmooth simulate --out $(OUT)

# Every smoothing method on the same demonstration, without the plant (core only).
methods: venv
	$(BIN)/telesmooth demo --out out/methods

# Two workers (the suite's files spread over both cores; each file's tests stay on one worker,
# so a module's process fixture runs once). `.venv/bin/python -m pytest -q -m "not process"`
# skips the real processes.
test: venv
	$(BIN)/python -m pytest -q -n 2 --dist loadfile

# Static checks ([tool.ruff] in pyproject.toml); CI runs them before the tests.
lint: venv
	$(BIN)/ruff check .

bench: venv
	$(BIN)/telesmooth bench --out out/bench

clean:
	rm -rf $(VENV) out .pytest_cache .hypothesis
