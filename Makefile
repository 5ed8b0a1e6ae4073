# Set-up and entry points. `make run` and `make test` each create .venv and install poromech
# (pinned versions from pyproject.toml) on first use.
PYTHON ?= $(shell command -v python3.12 2>/dev/null || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: install run test lint docs clean

install: $(STAMP)

$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; assert sys.version_info[:2] == (3, 12), \
		f"poromech needs Python 3.12, {sys.executable} is {sys.version.split()[0]}: run make PYTHON=/path/to/python3.12"'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e ".[test,plot,dev]"
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/poromech run -o results/six_fractures_mechanics

test: $(STAMP)
	$(BIN)/python -m pytest

lint: $(STAMP)
	$(BIN)/ruff check poromech forms tests scripts

docs: $(STAMP)
	$(BIN)/python scripts/make_scene_doc.py

clean:
	rm -rf $(VENV) results
