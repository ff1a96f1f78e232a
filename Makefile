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

# Mitsuba's llvm_ad_rgb variant needs Debian's libLLVM; without it the
# benchmark falls back to scalar_rgb and says so.
bench: install
	$(BIN)/python -m pip install --quiet -e '.[bench,distributed]'
	@ls /usr/lib/*/libLLVM-19.so* >/dev/null 2>&1 || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null && \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19) >/dev/null 2>&1; } || \
	  echo "note: libllvm19 not installed; Mitsuba will run as scalar_rgb"
	$(BIN)/python benchmarks/bench.py $(BENCH_ARGS)

clean:
	rm -rf $(VENV) renders/*.png build *.egg-info
