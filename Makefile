# normbox-lab: the two commands of the contract are `make demo` and `make test`.
# Each sets everything up on a fresh machine.  `make demo` needs the package only: .venv, the
# package and its dependencies, and (as root, when missing) Debian's libllvm19 for Mitsuba's
# llvm_ad_spectral variant.  `make test` adds the dev extra (the outside client libraries the
# conformance tests drive the emulators with, pytest, hypothesis, ruff) and Debian's chromium
# for the report's headless-browser test.

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
RUNTIME := $(VENV)/.normbox-runtime
STAMP  := $(VENV)/.normbox-installed

.PHONY: demo test test-slow test-all setup setup-runtime lint clean bench-gpu

setup: $(STAMP)

setup-runtime: $(RUNTIME)

$(RUNTIME): pyproject.toml setup.py
	@if [ "$$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1 \
	    && ! ldconfig -p 2>/dev/null | grep -q 'libLLVM-19\|libLLVM.so.19'; then \
	  echo ">> installing Debian libllvm19 (Mitsuba's llvm_ad_spectral needs libLLVM >= 16)"; \
	  DEBIAN_FRONTEND=noninteractive apt-get install -y -q libllvm19 >/dev/null 2>&1 \
	  || (apt-get update -q >/dev/null 2>&1 && DEBIAN_FRONTEND=noninteractive apt-get install -y -q libllvm19 >/dev/null 2>&1) \
	  || echo "WARNING: could not install libllvm19; Mitsuba will fall back to scalar_spectral (slow)"; \
	elif ! ldconfig -p 2>/dev/null | grep -q 'libLLVM-19\|libLLVM.so.19'; then \
	  echo "WARNING: libLLVM 19 not found and not root; Mitsuba may fall back to scalar_spectral (slow)"; \
	fi
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e .
	$(PY) -m normbox_lab.predict.mitsuba_setup
	@touch $(RUNTIME)

$(STAMP): $(RUNTIME)
	@if [ "$$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1 \
	    && ! command -v chromium >/dev/null 2>&1; then \
	  echo ">> installing Debian chromium (the report's browser test reads the report headless)"; \
	  DEBIAN_FRONTEND=noninteractive apt-get install -y -q chromium >/dev/null 2>&1 \
	  || (apt-get update -q >/dev/null 2>&1 && DEBIAN_FRONTEND=noninteractive apt-get install -y -q chromium >/dev/null 2>&1) \
	  || echo "WARNING: could not install chromium; the report's browser test will be skipped"; \
	fi
	$(PY) -m pip install -q -e '.[dev]'
	$(PY) -m pip install -q --no-deps --pre 'colour-specio==0.4.0a0'
	@touch $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -q

test-slow: $(STAMP)
	$(PY) -m pytest -q -m slow

test-all: $(STAMP)
	$(PY) -m pytest -q -m ''

demo: $(RUNTIME)
	$(VENV)/bin/normbox-lab demo

# On a machine with an NVIDIA GPU: the fast renderer's tests and `bench predict` in Mitsuba's
# cuda_ad_mono variant (the bench runs twice: the second finds Dr.Jit's kernel cache warm).
bench-gpu: $(STAMP)
	NORMBOX_FAST_VARIANT=cuda_ad_mono $(PY) -m pytest -q -m '' tests/predict/test_fastrender.py tests/predict/test_executors.py
	NORMBOX_FAST_VARIANT=cuda_ad_mono $(VENV)/bin/normbox-lab bench predict
	NORMBOX_FAST_VARIANT=cuda_ad_mono $(VENV)/bin/normbox-lab bench predict

lint: $(STAMP)
	$(VENV)/bin/ruff check normbox_lab drivers sim protocols tests

clean:
	rm -rf $(VENV) .cache .pytest_cache .hypothesis *.egg-info
