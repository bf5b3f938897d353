# rstrace: `make demo` runs the main job, `make test` runs the tests. Both set up .venv.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench extension clean

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[test,bench]"
	touch $(STAMP)

# The kernels the demo's BASE frames use (the BVH, hard light, a perspective camera) compile
# in a background warm-cache, one process per core, while the demo starts and renders; each
# kernel compiles in one process only (the others wait for it and load it), with progress
# (kernels done/total); a warm cache only loads them. On a cold cache the interpolated frame
# is the base tracer's while the cell build's kernels compile beside it (build_beside.py).
demo: $(STAMP)
	$(PY) examples/demo.py --out out/demo --warm-cache

# The bpy tests run in their own process: bpy brings its own TBB/Embree and changes which
# numba threading layer the core tests would get.
test: $(STAMP)
	$(PY) -m ruff check rstrace_engine addon tests examples scripts
	$(PY) -m pytest -q tests --ignore=tests/blender
	$(PY) -m pytest -q tests/blender

lint: $(STAMP)
	$(PY) -m ruff check rstrace_engine addon tests examples scripts

# Blender extension zips, one per platform: dist/rstrace-<version>-<platform>.zip.
# EXT_PLATFORMS=linux-x64 skips the (optional) Windows and macOS wheel downloads.
EXT_PLATFORMS ?= linux-x64 windows-x64 macos-arm64
extension: $(STAMP)
	$(PY) scripts/build_extension.py --platforms $(EXT_PLATFORMS)

bench: $(STAMP)
	$(PY) -m rstrace_engine.bench raycast
	$(PY) -m rstrace_engine.bench frame

clean:
	rm -rf $(VENV) dist build out *.egg-info
