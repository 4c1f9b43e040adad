# The two commands of the README:
#   make demo   install what is missing, build, run every method on a built-in problem
#   make test   install what is missing, build, run ctest and pytest
PY      ?= python3
BUILD   ?= build
APT_PKGS = libeigen3-dev libsuitesparse-dev libopenblas0-pthread doctest-dev
PIP_PKGS = "numpy>=1.23" "scipy>=1.9" "pyamg>=5.0" "pybind11>=2.12" "scikit-build-core>=0.8" "matplotlib>=3.5" \
           "pytest>=7" "hypothesis>=6" ninja "cmake>=3.18"
SUDO    := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
# Every recipe line fails on the first failing command, including inside a pipe: a failed
# build must fail `make demo` and `make test`, never leave an older nrmicp importable.
SHELL   := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
# pip's "Running pip as the 'root' user" warning, silenced without a pipe that could hide errors
export PIP_ROOT_USER_ACTION := ignore
PIP     = $(PY) -m pip install -q --disable-pip-version-check

.PHONY: demo test deps install ctest pytest bench clean

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

bench: install
	$(PY) -m nrmicp bench

clean:
	rm -rf $(BUILD)
