# The two commands of the README:
#   make demo   install what is missing, build, run every method on a built-in problem
#   make test   install what is missing, build, run ctest and pytest
PY      ?= python3
BUILD   ?= build
APT_PKGS = libeigen3-dev libsuitesparse-dev libopenblas0-pthread doctest-dev
PIP_PKGS = "numpy>=1.23" "scipy>=1.9" "pyamg>=5.0" "pybind11>=2.12" "scikit-build-core>=0.8" "matplotlib>=3.5" \
           "pytest>=7" "hypothesis>=6" "scikit-fem>=8" ninja "cmake>=3.18"
SUDO    := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
# Every recipe line fails on the first failing command, including inside a pipe: a failed
# build must fail `make demo` and `make test`, never leave an older nrmicp importable.
SHELL   := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
# pip's "Running pip as the 'root' user" warning, silenced without a pipe that could hide errors
export PIP_ROOT_USER_ACTION := ignore
PIP     = $(PY) -m pip install -q --disable-pip-version-check

.PHONY: demo test deps install ctest pytest sanitize bench clean

demo: install
	$(PY) -m nrmicp demo

test: install ctest pytest

deps:
	@missing=""; for p in $(APT_PKGS); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  echo "installing Debian packages:$$missing"; \
	  $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $$missing >/dev/null; \
	fi
	@$(PY) -m pip --version >/dev/null 2>&1 || { echo "installing python3-pip"; \
	  $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq python3-pip >/dev/null; }
	@$(PIP) $(PIP_PKGS) || { echo "make: pip could not install $(PIP_PKGS)." \
	  "With Debian's own python3 (externally managed, PEP 668) use a venv:" \
	  "python3 -m venv .venv && make $(MAKECMDGOALS) PY=.venv/bin/python" >&2; exit 1; }

install: deps
	$(PIP) --no-build-isolation .
	@cd /tmp && $(PY) -c "import nrmicp; print('nrmicp', nrmicp.__version__, 'installed; backends:', nrmicp.backends())"

ctest: deps
	cmake -S . -B $(BUILD)/ctest -G Ninja -DNRMICP_BUILD_TESTS=ON -DCMAKE_BUILD_TYPE=Release
	cmake --build $(BUILD)/ctest
	ctest --test-dir $(BUILD)/ctest --output-on-failure

pytest:
	$(PY) -m pytest -q tests

# The Python module built with ASan + UBSan (a separate build, imported through PYTHONPATH with
# libasan preloaded, and libstdc++ too: ASan's __cxa_throw interceptor needs it at start-up;
# CPython's own allocations are not leak-checked), then the bad-input,
# robustness and fuzz tests run against it. SANITIZE_FUZZ_EXAMPLES sets the fuzz slice.
# (The C++ tests with the sanitizers: README "Layout", -DNRMICP_SANITIZE=ON.)
SANITIZE_FUZZ_EXAMPLES ?= 300
sanitize: deps
	cmake -S . -B $(BUILD)/sanitize -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DNRMICP_SANITIZE=ON \
	  -DNRMICP_BUILD_PYTHON=ON -DNRMICP_BUILD_TESTS=OFF -DPython_EXECUTABLE=$$($(PY) -c 'import sys; print(sys.executable)') \
	  -Dpybind11_DIR=$$($(PY) -m pybind11 --cmakedir)
	cmake --build $(BUILD)/sanitize --target _core
	rm -rf $(BUILD)/sanitize/pkg && mkdir -p $(BUILD)/sanitize/pkg && cp -r python/nrmicp $(BUILD)/sanitize/pkg/ \
	  && cp $(BUILD)/sanitize/_core*.so $(BUILD)/sanitize/pkg/nrmicp/
	LD_PRELOAD="$$($(CXX) -print-file-name=libasan.so) $$($(CXX) -print-file-name=libstdc++.so)" ASAN_OPTIONS=detect_leaks=0 \
	  UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 PYTHONPATH=$(BUILD)/sanitize/pkg NRMICP_SANITIZE=1 \
	  NRMICP_FUZZ_EXAMPLES=$(SANITIZE_FUZZ_EXAMPLES) $(PY) -m pytest -q -p no:cacheprovider \
	  tests/test_bad_input.py tests/test_robustness.py tests/test_fuzz.py

bench: install
	$(PY) -m nrmicp bench

clean:
	rm -rf $(BUILD)
