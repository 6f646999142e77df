# The two commands a new user needs: `make demo` (the main job) and `make test` (the whole test suite).
# Both create or reuse the virtual environment in $(VENV) and install what they need.

PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# Real data: VPR_UNCERTAINTY_DATA if set, else ../shared/data beside the checkout.
DATA ?= $(if $(VPR_UNCERTAINTY_DATA),$(VPR_UNCERTAINTY_DATA),$(abspath ../shared/data))

.PHONY: demo test lint bench clean

$(STAMP): pyproject.toml Makefile
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $@

demo: $(STAMP)
	$(BIN)/vpr-uncertainty evaluate \
		"$(DATA)/vprbench/precomputed_matches/corridor/NetVLAD/precomputed_data_corrected.npy" \
		--gt "$(DATA)/vprbench/corridor/ground_truth_new.npy" \
		--methods RS,SD,SU,PA,L2,BM,margin --json runs/demo/results.json --plot runs/demo/pr_curves.png

test: $(STAMP)
	$(BIN)/ruff check src tests benchmarks
	VPR_UNCERTAINTY_DATA="$(DATA)" $(BIN)/python -m pytest

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_scores.py

clean:
	rm -rf $(VENV) runs .pytest_cache .ruff_cache .hypothesis
