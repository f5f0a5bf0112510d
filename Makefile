# One venv, made by `make setup`; `make demo` and `make test` call it themselves.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
DATA    ?= ../shared/data
DEMO_DIR ?= out/demo

.PHONY: setup system-deps demo test test-fast bench clean

setup: $(STAMP)

# Debian packages the tests need: chromium (the web viewer test), iproute2 (network namespaces).
system-deps:
	@command -v chromium >/dev/null 2>&1 && command -v ip >/dev/null 2>&1 || { \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends chromium iproute2; }

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

demo: setup
	$(BIN)/python -m nodes.demo --out $(DEMO_DIR) --data $(DATA)

test: setup system-deps
	MOCAP_RT_DATA=$(DATA) $(BIN)/python -m pytest -q

test-fast: setup
	MOCAP_RT_DATA=$(DATA) $(BIN)/python -m pytest -q -m "not slow"

bench: setup
	MOCAP_RT_DATA=$(DATA) $(BIN)/python -m bench

clean:
	rm -rf $(VENV) out .pytest_cache
