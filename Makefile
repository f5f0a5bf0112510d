# One venv, made by `make setup`; `make demo` and `make test` call it themselves.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
GST_STAMP := $(VENV)/.installed-gst
# uv (from PyPI, into the venv) installs the project: ~40 s from a cold cache where pip takes ~3.5 min.
# --compile-bytecode: uv writes no .pyc by default, and where PYTHONDONTWRITEBYTECODE is set (this
# workplace) no process ever does, so each one compiled numpy's, scipy's and numba's sources again
# at import (a perceiver's first frame 2.5-3.4 s after start; 0.9-1.4 s with the .pyc, ~9 s once here)
UV      := $(BIN)/uv pip install --python $(BIN)/python --quiet --compile-bytecode
DATA    ?= ../shared/data
DEMO_DIR ?= out/demo

.PHONY: setup kernels system-deps gst-bindings demo test test-gst test-fast bench clean

# the venv, then every numba kernel compiled once, in one process, into the cache that
# every node, test and demo loads (mocap_rt/warmup.py: a no-op while the kernel sources
# are unchanged; the service also checks it before starting its nodes)
setup: $(STAMP) gst-bindings kernels

kernels: $(STAMP)
	$(BIN)/python -m compileall -q mocap_rt nodes bench >/dev/null    # our own .pyc too (see UV)
	MOCAP_RT_DATA=$(DATA) $(BIN)/python -m mocap_rt.warmup

# GStreamer (gst: camera sources, docs/sources.md) and what PyGObject builds against.
GST_DEBS := gstreamer1.0-tools gstreamer1.0-plugins-base gstreamer1.0-plugins-good gstreamer1.0-plugins-bad \
	gstreamer1.0-libav gir1.2-gstreamer-1.0 gir1.2-gst-plugins-base-1.0 libgirepository1.0-dev libcairo2-dev pkg-config

# Debian packages the tests need: chromium (the web viewer test), iproute2 (network namespaces),
# GStreamer (the gst: source tests).
system-deps:
	@command -v chromium >/dev/null 2>&1 && command -v ip >/dev/null 2>&1 && command -v openssl >/dev/null 2>&1 && dpkg -s $(GST_DEBS) >/dev/null 2>&1 || { \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends chromium iproute2 openssl $(GST_DEBS); }

# PyGObject into the venv (the `gst` extra) once GStreamer's headers are there (make system-deps);
# without them the rest of the project works and gst: sources say what to install.
gst-bindings: $(STAMP)
	@test -f $(GST_STAMP) || { if pkg-config --exists gobject-introspection-1.0 cairo 2>/dev/null; then \
	  $(UV) -e '.[dev,service,gst]' && touch $(GST_STAMP); \
	  else echo "note: GStreamer development files missing (make system-deps): gst: sources unavailable"; fi; }

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet uv
	$(UV) -e '.[dev,service]'
	rm -f $(GST_STAMP)
	touch $(STAMP)

# the demo does not wait for GStreamer's bindings (PyGObject, built from source: ~1 min)
demo: $(STAMP) kernels
	$(BIN)/python -m nodes.demo --out $(DEMO_DIR) --data $(DATA)

# two pytest-xdist workers (TEST_JOBS=1: one process): the modules that start clusters go to
# one worker as one unit, the library tests to the other at a lower priority (tests/conftest.py:
# two service clusters at once on 2 cores lose frames). A worker that crashes is not replaced:
# the test it ran fails, naming the crash, and the others finish (xdist 3.8 with loadscope hung
# at 99 % after replacing one: its crashed worker's completed scopes come back as empty work
# units, pytest-dev/pytest-xdist#1323 and #1378)
TEST_JOBS ?= 2
test:
	$(MAKE) -j2 test-gst kernels          # apt and the venv, then PyGObject's build and the kernel warm-up, side by side
	MOCAP_RT_DATA=$(DATA) $(BIN)/python -m pytest -q --durations=15 \
	  $(if $(filter-out 1,$(TEST_JOBS)),-n $(TEST_JOBS) --dist loadscope --max-worker-restart=0)

# the Debian packages (apt) and the venv (uv) side by side, then PyGObject (needs both)
test-gst: system-deps $(STAMP)
	$(MAKE) gst-bindings

test-fast: setup
	MOCAP_RT_DATA=$(DATA) $(BIN)/python -m pytest -q -m "not slow"

bench: setup
	MOCAP_RT_DATA=$(DATA) $(BIN)/python -m bench

clean:
	rm -rf $(VENV) out .pytest_cache
	find mocap_rt -path "*__pycache__*" \( -name "*.nb[ic]" -o -name "mocap_rt-numba-kernels.*" \) -delete
