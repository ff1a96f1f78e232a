# Two commands do everything on a fresh machine with only python3:
#   make render   create .venv, install wavefront, render the default scene
#   make test     same install plus the test extras, run the suite
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
SCENE  ?= scenes/three_spheres.yaml
OUT    ?= renders/three_spheres.png

.PHONY: render test install install-test bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# Stamp files so a second `make` does not reinstall; pyproject changes do.
$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(VENV)/.installed-test: pyproject.toml $(VENV)/.installed
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $@

install: $(VENV)/.installed
install-test: $(VENV)/.installed-test

render: install
	mkdir -p $(dir $(OUT))
	$(BIN)/wavefront render $(SCENE) -o $(OUT)

test: install-test
	$(BIN)/python -m pytest

clean:
	rm -rf $(VENV) renders/*.png build *.egg-info
