# Everything a fresh Debian/Ubuntu machine needs: `make demo`, `make test`.
PY      ?= python3
VENV    := .venv
VPY     := $(VENV)/bin/python
STAMP   := $(VENV)/.installed
SCENE   ?= scenes/apple_orchard.toml
OUT     ?= out

.PHONY: demo test docs bench llvm test-tools bytecode clean

# Dr.Jit needs libLLVM >= 17; Debian 12 ships libllvm19. The package's own finder
# (simlidar_mi/_runtime/llvm.py, standard library only, so it runs before the venv exists)
# answers: exit 0 found, 3 none. apt-get runs only for 3, and only as root.
llvm:
	@$(PY) -I simlidar_mi/_runtime/llvm.py; rc=$$?; \
	if [ $$rc = 0 ]; then :; \
	elif [ $$rc != 3 ]; then \
	  echo "WARNING: could not check for libLLVM >= 17 ('$(PY) simlidar_mi/_runtime/llvm.py' exited $$rc)"; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  echo "installing libllvm19 with apt-get"; \
	  { apt-get install -y --no-install-recommends libllvm19 || \
	    { apt-get update && apt-get install -y --no-install-recommends libllvm19; }; } && \
	  $(PY) -I simlidar_mi/_runtime/llvm.py || \
	  { echo "apt-get could not install libllvm19 (dpkg locked or offline?); install it and rerun"; exit 1; }; \
	else \
	  echo "WARNING: no libLLVM >= 17; install it with: sudo apt-get install -y libllvm19"; \
	fi

# The interop tests' C readers (tests/test_interop_grid.py): cfchecker needs the udunits2 library
# (looked up as cfunits looks it up), the classic-format check runs netCDF's nccopy. apt-get runs
# only when one is missing, and only as root; without them the CF checks skip saying what to
# install and the nccopy conversions are left out (the netCDF4 classic copy still runs).
TEST_APT := libudunits2-0 netcdf-bin
test-tools:
	@if $(PY) -c "import ctypes.util as u, sys; sys.exit(u.find_library('udunits2') is None)" && \
	   command -v nccopy >/dev/null; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  echo "installing $(TEST_APT) with apt-get (the interop tests' readers)"; \
	  { apt-get install -y --no-install-recommends $(TEST_APT) || \
	    { apt-get update && apt-get install -y --no-install-recommends $(TEST_APT); }; } >/dev/null || \
	  { echo "apt-get could not install $(TEST_APT) (dpkg locked or offline?); install them and rerun"; exit 1; }; \
	else \
	  echo "WARNING: the CF and netCDF classic checks need: sudo apt-get install -y $(TEST_APT)"; \
	fi

# The install shows pip's own progress on a terminal and one line per stage when piped. `make demo`
# installs the package and what it runs on (STAMP); `make test` and `make docs` add their extras
# on top (.installed-test, .installed-docs), so a demo does not wait for the test tools.
$(STAMP): pyproject.toml
	@command -v $(PY) >/dev/null || { echo "python3 is required"; exit 1; }
	@[ -x $(VPY) ] || { echo "[1/3] creating $(VENV)"; $(PY) -m venv $(VENV); } || { echo "venv failed: apt-get install -y python3-venv"; exit 1; }
	@echo "[2/3] upgrading pip"; $(VPY) -m pip install -q --upgrade pip
	@echo "[3/3] installing simlidar-mi and what it runs on (Mitsuba 3, Dr.Jit, NumPy, SciPy," \
	  "laspy, xarray, Dask, ...; first time: a few minutes)"; \
	if [ -t 1 ]; then q=; else q=-q; fi; $(VPY) -m pip install $$q -e .
	@touch $(STAMP)
	@echo "installed: $$($(VPY) -c 'import simlidar_mi; print(simlidar_mi.__version__)' 2>/dev/null) in $(VENV)"

EXTRAS_test := pytest, pytest-xdist, hypothesis, sybil, Sphinx, the CF checkers, OpenImageIO, build
EXTRAS_docs := Sphinx, MyST, furo
$(VENV)/.installed-%: $(STAMP) pyproject.toml
	@echo "installing the $* extras ($(EXTRAS_$*); first time: a few minutes)"; \
	if [ -t 1 ]; then q=; else q=-q; fi; $(VPY) -m pip install $$q -e '.[$*]'
	@touch $@

# An editable install compiles no bytecode, and PYTHONDONTWRITEBYTECODE (set in many containers)
# stops Python from caching it: every command would compile the package again (~0.05-0.08 s).
# compileall writes what is missing or stale, as a wheel install would.
bytecode: $(STAMP)
	@$(VPY) -m compileall -q simlidar_mi plugins >/dev/null

demo: llvm $(STAMP) bytecode
	$(VENV)/bin/simlidar-mi scan $(SCENE) --out $(OUT)/apple_orchard
	$(VENV)/bin/simlidar-mi preview $(SCENE) --out $(OUT)/apple_orchard/preview.png
	$(VENV)/bin/simlidar-mi gapfraction scenes/strawberry_plot.toml --out $(OUT)/strawberry
	$(VENV)/bin/simlidar-mi compare scenes/strawberry_manifest.csv --out $(OUT)/compare
	@echo "outputs in $(OUT)/"

# The suite runs on TEST_JOBS worker processes (pytest-xdist; 2 for the 2-core CI machine, 0 for
# one process); tests sharing a module's scan, docs build or Dask cluster stay on one worker
# (tests/conftest.py). The 20 slowest are listed at the end (CONTRIBUTING.md says why they cost).
TEST_JOBS ?= 2
test: llvm test-tools $(VENV)/.installed-test bytecode
	$(VPY) -m pytest -q -n $(TEST_JOBS) --dist loadgroup --durations=20

# The documentation (docs/, Sphinx + MyST) with its references generated from the code; any
# warning (a broken page, reference or generated table) fails the build; -E reads every page
# again, as an incremental build does not repeat the warnings of pages it did not re-read.
docs: llvm $(VENV)/.installed-docs bytecode
	$(VENV)/bin/sphinx-build -E -b html -W --keep-going docs docs/_build/html
	@echo "docs in docs/_build/html/index.html"

bench: llvm $(STAMP) bytecode
	$(VPY) bench/run_all.py

clean:
	rm -rf $(VENV) $(OUT) build docs/_build *.egg-info
