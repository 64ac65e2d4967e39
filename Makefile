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

.PHONY: run test lint bench clean

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(DEVSTAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[dev]'
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

test: $(DEVSTAMP) $(PEERSTAMP)
	bash .ci/sysdeps
	$(MAKE) $(OPCUA_STAMP)
	$(BIN)/python -m pytest -q

lint: $(DEVSTAMP)
	$(BIN)/ruff check . && $(BIN)/ruff format --check .

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) $(PEERS) .pytest_cache $(OPCUA_PEER)/node_modules
