# Set-up and entry points. `make run` and `make test` each create .venv and install poromech on
# first use, every package at the version pinned in constraints.txt (the image uses the same file).
PYTHON ?= $(shell command -v python3.12 2>/dev/null || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
EXTRAS := test,plot,dev
PIP_INSTALL := $(BIN)/pip install --quiet --disable-pip-version-check -c constraints.txt

.PHONY: install check-cc run test lint docs lock clean

install: $(STAMP)

# DOLFINx compiles the forms to C at run time (FFCx + cffi), with the compiler Python was built
# with ($CC, else sysconfig's CC), the C library headers and Python.h: one line says what is missing.
define CHECK_CC
@cc=$$($(PYTHON) -c 'import os, sysconfig; print((os.environ.get("CC") or sysconfig.get_config_var("CC") or "cc").split()[0])'); \
inc=$$($(PYTHON) -c 'import sysconfig; print(sysconfig.get_path("include"))'); \
fail() { echo "make install: DOLFINx compiles forms at run time, and $$1: install $$2" >&2; exit 1; }; \
command -v "$$cc" >/dev/null || fail "$$cc, the C compiler Python names, is not found" \
	"it (Debian/Ubuntu: sudo apt-get install gcc libc6-dev, or build-essential)"; \
test -f "$$inc/Python.h" || fail "$$inc/Python.h is missing" \
	"the Python headers (Debian/Ubuntu: sudo apt-get install python3.12-dev)"; \
printf '#include <Python.h>\n' | "$$cc" -fsyntax-only -I"$$inc" -x c - 2>/dev/null || fail \
	"$$cc cannot compile against <Python.h>" "the C library headers (Debian/Ubuntu: sudo apt-get install libc6-dev)"
endef

$(STAMP): pyproject.toml constraints.txt
	@$(PYTHON) -c 'import sys; assert sys.version_info[:2] == (3, 12), \
		f"poromech needs Python 3.12, {sys.executable} is {sys.version.split()[0]}: run make PYTHON=/path/to/python3.12"'
	$(CHECK_CC)
	$(PYTHON) -m venv $(VENV)
	$(PIP_INSTALL) pip setuptools
	$(PIP_INSTALL) --no-build-isolation -e ".[$(EXTRAS)]"
	cp scripts/dolfinx_mpi_first.pth \
		"$$($(BIN)/python -c 'import sysconfig; print(sysconfig.get_path("purelib"))')/"
	touch $(STAMP)

check-cc:
	$(CHECK_CC)

run: $(STAMP)
	$(BIN)/poromech run -o results/six_fractures --overwrite

test: $(STAMP)
	$(BIN)/python -m pytest

lint: $(STAMP)
	$(BIN)/ruff check poromech forms tests scripts

docs: $(STAMP)
	$(BIN)/python scripts/make_scene_doc.py

# Re-resolve constraints.txt: a fresh venv with the newest pip and setuptools, the pinned direct
# dependencies of pyproject.toml and whatever they pull in today. Review the diff, set the
# setuptools of [build-system] in pyproject.toml to the one it records, then commit both.
lock:
	@tmp=$$(mktemp -d) && trap 'rm -rf "$$tmp"' EXIT && \
	$(PYTHON) -m venv "$$tmp" && \
	"$$tmp/bin/pip" install --quiet --disable-pip-version-check --upgrade pip setuptools wheel && \
	"$$tmp/bin/pip" install --quiet --disable-pip-version-check ".[$(EXTRAS)]" && \
	{ echo "# Every package of a poromech environment, at the version the results were produced with."; \
	  echo "# Used as 'pip install -c constraints.txt' by make install and the Dockerfile;"; \
	  echo "# regenerate with 'make lock' (a clean venv, .[$(EXTRAS)] plus pip, setuptools, wheel)."; \
	  echo "# Python $$("$$tmp/bin/python" -c 'import platform; print(platform.python_version())'), resolved $$(date -u +%F)"; \
	  "$$tmp/bin/pip" freeze --all --exclude poromech; } > constraints.txt
	@echo "constraints.txt: $$(grep -c '==' constraints.txt) pinned packages"

clean:
	rm -rf $(VENV) results
