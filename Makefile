# Two commands on a fresh machine: `make run` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEVSTAMP := $(VENV)/.installed-dev
PEERS := .venv-peers
PEERSTAMP := $(PEERS)/.installed
# node-opcua, the OPC UA client peer of the tests (pinned by its package-lock.json)
OPCUA_PEER := tests/peers/opcua
OPCUA_STAMP := $(OPCUA_PEER)/node_modules/.package-lock.json

.PHONY: run test check lint bench clean public-data tep-studio-data

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# the project's bytecode compiled as a wheel install compiles it: a `diag` process then does
# not compile its modules from source each start where PYTHONDONTWRITEBYTECODE is set
# (0.08-0.1 s CPU of a `diag train` process, issue 37)
COMPILE := $(BIN)/python -m compileall -q diag_plugin historian connectors
# and the Wang-Mendel kernels compiled into numba's cache at install, not in the user's first
# `diag unit build` (200 tags x 10 days at 1 min: parent 18.8 s CPU on a fresh checkout
# against 7.2 s warm, docs/how-to/unit-from-history.md)
WARM := $(BIN)/python -c "from diag_plugin.unitbuild.build import warm_kernels; warm_kernels()"

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	$(COMPILE)
	$(WARM)
	touch $@

$(DEVSTAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	$(COMPILE)
	$(WARM)
	touch $(STAMP) $@

# test-only peers in their own venv (pyfuzzylite pins numpy<2), from pyproject's `peers` extra
$(PEERSTAMP): pyproject.toml
	$(PY) -m venv $(PEERS)
	$(PEERS)/bin/python -m pip install --quiet $$($(PY) -c "import tomllib; print(*tomllib.load(open('pyproject.toml', 'rb'))['project']['optional-dependencies']['peers'])")
	touch $@

# the live plug-in on the embedded default: a simulated valve plant served over Modbus TCP,
# diagnosed each cycle, results over OPC UA and Modbus; a scripted fault is raised,
# acknowledged and cleared, then it stops (`.venv/bin/diag run` runs until Ctrl-C)
run: $(STAMP)
	$(BIN)/diag run --duration 160

$(OPCUA_STAMP): $(OPCUA_PEER)/package-lock.json
	cd $(OPCUA_PEER) && npm ci --no-audit --no-fund --loglevel=error
	touch $@

# the whole suite (CI runs this), on TEST_JOBS pytest-xdist workers, a test file per worker
# at a time so that a file's module fixtures are built once (TEST_JOBS=0: one process).
# Three workers on two cores: many tests wait on real time (live loops, held locks,
# restarts), and the third fills those waits (fresh clone, quiet machine: 8 min 10 s at
# 1,353 tests on 2026-11-28, `make check` 2 min 43 s; docs/reference/testing.md has the
# tiers' costs)
TEST_JOBS ?= 3
XDIST = $(if $(filter 0,$(TEST_JOBS)),,-n $(TEST_JOBS) --dist loadfile)

test: $(DEVSTAMP) $(PEERSTAMP)
	bash .ci/sysdeps
	$(MAKE) $(OPCUA_STAMP)
	-$(MAKE) public-data
	$(BIN)/python -m pytest -q $(XDIST)

# the fast tier while working: everything but the tests marked slow (tests/conftest.py
# lists them, from a --durations profile), same workers; the full suite stays `make test`
check: $(DEVSTAMP)
	$(BIN)/python -m pytest -q -m "not slow" $(XDIST)

lint: $(DEVSTAMP)
	$(BIN)/ruff check . && $(BIN)/ruff format --check .

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do $(BIN)/python $$b || exit 1; done

# public plants for `diag benchmark --plant tep|tep-studio` (docs/results/), kept outside
# the repository; tests skip with the reason when they are absent
DATA := $(HOME)/.cache/diag-plugin
BRAATZ := $(DATA)/tep-braatz/bibmon/tennessee_eastman/d21_te.dat
TEPVENV := $(DATA)/tepvenv

# the classic Tennessee Eastman data (Braatz), as shipped inside the bibmon 1.2.0 wheel: the
# wheel alone (no dependencies), the .dat files unpacked from it
public-data: $(BRAATZ)
$(BRAATZ): | $(BIN)/python
	mkdir -p $(DATA)/wheels $(DATA)/tep-braatz
	$(BIN)/python -m pip download --quiet --no-deps bibmon==1.2.0 -d $(DATA)/wheels
	$(BIN)/python -c "import sys, zipfile; z = zipfile.ZipFile(sys.argv[1]); \
	z.extractall(sys.argv[2], [n for n in z.namelist() if n.endswith('.dat')])" \
	  $(DATA)/wheels/bibmon-1.2.0-py3-none-any.whl $(DATA)/tep-braatz

# tep-studio 0.2.0 (a C build through cffi; gcc) in its own venv, then its runs (~30 min)
tep-studio-data:
	test -x $(TEPVENV)/bin/python || $(PY) -m venv $(TEPVENV)
	$(TEPVENV)/bin/python -m pip install --quiet cffi numpy scipy pandas gymnasium "setuptools>=68" wheel
	$(TEPVENV)/bin/python -m pip install --quiet --no-deps --no-build-isolation tep-studio==0.2.0
	$(TEPVENV)/bin/python benchmarks/tep_studio_runs.py

clean:
	rm -rf $(VENV) $(PEERS) .pytest_cache $(OPCUA_PEER)/node_modules
