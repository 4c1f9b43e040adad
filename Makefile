# The two commands of the README:
#   make demo   install what is missing, build, run every method on a built-in problem
#   make test   install what is missing, build, run ctest, pytest and the MPI tests (mpitest)
PY      ?= python3
BUILD   ?= build
# PETSc, MPI and pkg-config too: `install` then builds nrmicp._petsc (the Newton member on PETSc)
APT_PKGS = libeigen3-dev libsuitesparse-dev libopenblas0-pthread doctest-dev pkg-config $(MPI_APT)
PIP_PKGS = "numpy>=1.23" "scipy>=1.9" "pyamg>=5.0" "pybind11>=2.12" "scikit-build-core>=0.8" "matplotlib>=3.5" \
           "pytest>=7" "hypothesis>=6" "piqp>=0.4" "scikit-fem>=8" ninja "cmake>=3.18"
SUDO    := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
# Every recipe line fails on the first failing command, including inside a pipe: a failed
# build must fail `make demo` and `make test`, never leave an older nrmicp importable.
SHELL   := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
# pip's "Running pip as the 'root' user" warning, silenced without a pipe that could hide errors
export PIP_ROOT_USER_ACTION := ignore
PIP     = $(PY) -m pip install -q --disable-pip-version-check

# The distributed part (nrmicp.distributed, README "Beyond one machine"): Debian's PETSc 3.18 with
# hypre and Open MPI. Debian's petsc4py is built against numpy 1.x, so its tests run in a venv with
# numpy<2 that also sees $(PY)'s packages (nrmicp); a Python other than 3.11 builds petsc4py
# 3.18.5 from source against the same PETSc instead (numpy 2 works; measured 2.3 CPU-minutes).
MPI_APT  = petsc-dev python3-petsc4py-real openmpi-bin libopenmpi-dev
PETSC_DIR_DEB = /usr/lib/petscdir/petsc3.18/x86_64-linux-gnu-real
MPI_VENV = $(abspath $(BUILD)/mpi-venv)

.PHONY: demo test deps install ctest ctest-eigen pytest mpideps mpitest sanitize bench golden golden-diff clean

demo: install
	$(PY) -m nrmicp demo

test: install ctest ctest-eigen pytest mpitest

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

# SuiteSparse required here: a CMake that stops finding it fails, instead of dropping the
# CHOLMOD/UMFPACK tests (the Python side: tests/test_required.py).
ctest: deps
	cmake -S . -B $(BUILD)/ctest -G Ninja -DNRMICP_BUILD_TESTS=ON -DNRMICP_REQUIRE_SUITESPARSE=ON -DCMAKE_BUILD_TYPE=Release
	cmake --build $(BUILD)/ctest
	ctest --test-dir $(BUILD)/ctest --output-on-failure

# The Eigen-only configuration the README advertises (no SuiteSparse): test_methods in it.
ctest-eigen: deps
	cmake -S . -B $(BUILD)/ctest-eigen -G Ninja -DNRMICP_BUILD_TESTS=ON -DNRMICP_USE_SUITESPARSE=OFF \
	  -DNRMICP_TESTS=test_methods -DCMAKE_BUILD_TYPE=Release
	cmake --build $(BUILD)/ctest-eigen
	ctest --test-dir $(BUILD)/ctest-eigen --output-on-failure

pytest:
	$(PY) -m pytest -q tests

# Writes $(MPI_VENV)/python-path: the Python that has petsc4py and nrmicp.
mpideps: install
	@missing=""; for p in $(MPI_APT); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  echo "installing Debian packages:$$missing"; \
	  $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $$missing >/dev/null; \
	fi
	@mkdir -p $(MPI_VENV); \
	if [ "$$($(PY) -c 'import sys; print(sys.version_info[:2] == (3, 11))')" = True ]; then \
	  [ -x $(MPI_VENV)/bin/python ] || $(PY) -m venv --system-site-packages $(MPI_VENV); \
	  $(MPI_VENV)/bin/python -m pip install -q --disable-pip-version-check "numpy<2"; \
	  site=$$($(MPI_VENV)/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])'); \
	  { echo /usr/lib/petsc/lib/python3/dist-packages; \
	    $(PY) -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])'; } > $$site/nrmicp_mpi.pth; \
	  echo $(MPI_VENV)/bin/python > $(MPI_VENV)/python-path; \
	else \
	  PETSC_DIR=$(PETSC_DIR_DEB) PETSC_ARCH= $(PIP) --no-build-isolation --no-binary petsc4py "petsc4py==3.18.5"; \
	  $(PY) -c 'import sys; print(sys.executable)' > $(MPI_VENV)/python-path; \
	fi
	@cd /tmp && $$(cat $(MPI_VENV)/python-path) -c "import numpy, nrmicp.distributed; from petsc4py import PETSc; \
	  print('nrmicp.distributed ready: PETSc', PETSc.Sys.getVersion(), 'numpy', numpy.__version__)"

# The distributed tests, each under mpirun -n 1/2/3 (--oversubscribe; as root --allow-run-as-root).
mpitest: mpideps
	NRMICP_MPI_PYTHON=$$(cat $(MPI_VENV)/python-path) $$(cat $(MPI_VENV)/python-path) -m pytest -q tests_mpi

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

# The golden master (tests/golden/): every observable of ~650 stationary-member and ~730 Newton
# solves, recorded to $(GOLDEN).family.pkl / $(GOLDEN).newton.pkl. A developer's check that a
# refactoring changes nothing, bit for bit: record on the old build, then on the new one, and
#   make golden GOLDEN=before; (change, rebuild) make golden GOLDEN=after; make golden-diff BEFORE=before GOLDEN=after
GOLDEN ?= $(BUILD)/golden/current
golden: install
	mkdir -p $(dir $(GOLDEN))
	OPENBLAS_NUM_THREADS=1 $(PY) tests/golden/family.py $(GOLDEN).family.pkl
	OPENBLAS_NUM_THREADS=1 $(PY) tests/golden/newton.py $(GOLDEN).newton.pkl

golden-diff:
	$(PY) tests/golden/family.py --diff $(BEFORE).family.pkl $(GOLDEN).family.pkl
	$(PY) tests/golden/newton.py --diff $(BEFORE).newton.pkl $(GOLDEN).newton.pkl

clean:
	rm -rf $(BUILD)
