# pcreg: `make demo` and `make test` set themselves up on a fresh Debian machine.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP = $(VENV)/.pcreg-installed-$(OPEN3D)
# Debian's Python makes a venv with python3-venv (ensurepip); Open3D's wheel needs libusb at import; the headless viewer screenshots need lavapipe (Vulkan on the CPU);
# the cross-check tests compile tools/icp_min.c with gcc; `pcreg view --web` is tested in headless Chromium.
APT_PACKAGES := python3-venv libusb-1.0-0 mesa-vulkan-drivers libgomp1 gcc libc6-dev chromium
# OPEN3D=cuda installs the CUDA build of Open3D (907 MB) instead of the CPU build (312 MB).
OPEN3D ?= cpu
# One test process per CPU, each taking whole files (so a module's fixtures are built once): on 2 CPUs the
# suite of 1,335 tests took 16 min 44 s at a load average of 6-9 (18 CPU-minutes: 9 or more on 2 idle CPUs);
# when it was smaller, 7 minutes against 10-11 in one process. PYTEST_ARGS= runs it in one process.
PYTEST_ARGS ?= -n auto --dist loadfile
# Datumaro, whose VOC reader CVAT's mask import calls, reads `pcreg export`'s archive back in the tests; it pins
# opencv<5 and pillow 12, below pcreg's, so it gets a venv of its own (about 560 MB, 25 s to install).
DATUMARO := .venv-datumaro

.PHONY: setup sysdeps warm demo test check lint docs bench clean

setup: sysdeps $(STAMP) warm

# Compile the reference ICP's correspondence search once (numba, cached on disk next to the sources):
# no command pays the compilation afterwards; when the cache is current this only loads it (about a second).
warm: $(STAMP)
	@$(BIN)/python -m pcreg.kernels

sysdeps:
	@missing=""; for p in $(APT_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  echo "installing system packages:$$missing"; \
	  SUDO=""; [ "$$(id -u)" = 0 ] || SUDO=sudo; \
	  export DEBIAN_FRONTEND=noninteractive; \
	  $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq --no-install-recommends $$missing >/dev/null; \
	fi

# Installed again when pyproject.toml changed, or .venv is not whole (tools/setup_venv.sh: half made, made in
# another folder by a copied or moved checkout, its Python gone, pcreg not in it); after the system packages.
$(STAMP): pyproject.toml $(shell bash tools/setup_venv.sh check) | sysdeps
	@bash tools/setup_venv.sh install "$(PYTHON)" "$(OPEN3D)"

.PHONY: FORCE
FORCE:

demo: setup
	$(BIN)/pcreg demo --out out/demo --force

$(DATUMARO)/.installed:
	@$(DATUMARO)/bin/python -c 'import pip' 2>/dev/null || $(PYTHON) -m venv --clear $(DATUMARO)
	$(DATUMARO)/bin/python -m pip install -q "datumaro>=1.13,<2"
	@touch $@

test: setup lint docs $(DATUMARO)/.installed
	$(BIN)/python -m pytest -q $(PYTEST_ARGS)

# The edit loop: lint, types and the tests not marked slow (pyproject.toml's `slow` marker: commands
# stopped by signals, browsers and viewers, a dask cluster, whole evaluations and benchmarks in
# subprocesses), two processes taking tests one by one (whole files left one process with the CLI's
# 38 s file: 122 s against 97 s for 1,109 tests). `make test` runs all of them, with the docs.
check: setup lint
	$(BIN)/python -m pytest -q -m "not slow" -n 2 --dist load

# ruff (pyflakes, syntax and statement errors, line length) and mypy, configured in pyproject.toml.
lint: setup
	$(BIN)/ruff check pcreg tools tests
	$(BIN)/mypy

# The documentation site (mkdocs.yml) into build/site; strict: a broken link or a stale API name fails.
docs: setup
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --quiet

bench: setup
	$(BIN)/python tools/bench_registration.py --out out/bench
	$(BIN)/python tools/bench_classifier.py --out out/bench
	$(BIN)/python tools/bench_pipeline.py --out out/bench
	$(BIN)/python tools/bench_icp.py --out out/bench
	$(BIN)/python tools/bench_recording.py --out out/bench

clean:
	rm -rf $(VENV) $(VENV).lock $(DATUMARO) out build .pytest_cache .mypy_cache .ruff_cache
