# Everything a fresh Debian/Ubuntu machine needs: `make demo`, `make test`.
PY      ?= python3
VENV    := .venv
VPY     := $(VENV)/bin/python
STAMP   := $(VENV)/.installed
SCENE   ?= scenes/apple_orchard.toml
OUT     ?= out

.PHONY: demo test bench llvm clean

# Dr.Jit needs libLLVM >= 17; Debian 12 ships libllvm19. Installed only when
# running as root and none is found; otherwise simlidar_mi prints what to install.
llvm:
	@if ls /usr/lib/*/libLLVM*.so.1[7-9]* /usr/lib/*/libLLVM*.so.2[0-9]* /usr/lib/llvm-1[7-9]/lib/libLLVM*.so* /usr/lib/llvm-2[0-9]/lib/libLLVM*.so* >/dev/null 2>&1; then \
	  echo "libLLVM >= 17 found"; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  (apt-get install -y --no-install-recommends libllvm19 || (apt-get update && apt-get install -y --no-install-recommends libllvm19)); \
	else \
	  echo "WARNING: no libLLVM >= 17; install it with: sudo apt-get install -y libllvm19"; \
	fi

$(STAMP): pyproject.toml
	@command -v $(PY) >/dev/null || { echo "python3 is required"; exit 1; }
	@[ -x $(VPY) ] || $(PY) -m venv $(VENV) || { echo "venv failed: apt-get install -y python3-venv"; exit 1; }
	$(VPY) -m pip install -q --upgrade pip
	$(VPY) -m pip install -q -e '.[test]'
	@touch $(STAMP)

demo: llvm $(STAMP)
	$(VENV)/bin/simlidar-mi scan $(SCENE) --out $(OUT)/apple_orchard
	$(VENV)/bin/simlidar-mi preview $(SCENE) --out $(OUT)/apple_orchard/preview.png
	$(VENV)/bin/simlidar-mi gapfraction scenes/strawberry_plot.toml --out $(OUT)/strawberry
	$(VENV)/bin/simlidar-mi compare scenes/strawberry_manifest.csv --out $(OUT)/compare
	@echo "outputs in $(OUT)/"

test: llvm $(STAMP)
	$(VPY) -m pytest -q

bench: llvm $(STAMP)
	$(VPY) bench/run_all.py

clean:
	rm -rf $(VENV) $(OUT) build *.egg-info
