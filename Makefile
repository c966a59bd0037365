# rmbuild developer entry points. Everything runs from a local .venv built from the package registries.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
RUN_DIR ?= runs/default
PRESET ?= default
SEED ?= 7
REAL_DIR ?= runs/real
REAL_DATA ?= datasets/msft-ilc20/site1/F1

RM_CLI := MPLBACKEND=Agg $(BIN)/rmbuild

.PHONY: venv run run-real test bench bench-real bench-scan-rate fuzz lint clean

$(BIN)/python:
	@command -v $(PY) >/dev/null 2>&1 || { echo "error: $(PY) not found (rmbuild needs Python 3.11)"; exit 2; }
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install -q -e '.[dev,bench]'
	@touch $(STAMP)

venv: $(STAMP)

## make run: the whole pipeline on the embedded synthetic venue; prints where the results are
run: $(STAMP)
	$(RM_CLI) simulate $(RUN_DIR)/input --preset $(PRESET) --seed $(SEED) --force
	$(RM_CLI) ingest $(RUN_DIR)/input -w $(RUN_DIR)/workspace --force
	$(RM_CLI) optimize -w $(RUN_DIR)/workspace
	$(RM_CLI) export-map -w $(RUN_DIR)/workspace
	$(RM_CLI) evaluate -w $(RUN_DIR)/workspace
	$(RM_CLI) view -w $(RUN_DIR)/workspace --save $(RUN_DIR)/workspace/view.rrd
	$(RM_CLI) report -w $(RUN_DIR)/workspace
	@echo
	@echo "results:"
	@echo "  input files (simulated venue + truth/): $(RUN_DIR)/input"
	@echo "  workspace:                              $(RUN_DIR)/workspace"
	@echo "  stage reports:                          $(RUN_DIR)/workspace/*/report.json"
	@echo "  radio map:                              $(RUN_DIR)/workspace/map/"
	@echo "  the whole map for evo (one TUM file):   $(RUN_DIR)/workspace/map/evo/"
	@echo "  HTML report:                            $(RUN_DIR)/workspace/report.html"
	@echo "  rerun recording:                        $(RUN_DIR)/workspace/view.rrd  (open with: .venv/bin/rerun $(RUN_DIR)/workspace/view.rrd)"

## make run-real: the whole pipeline on the real sample in datasets/ (12 MS ILC 2.0 phone walks of one floor)
run-real: $(STAMP)
	$(RM_CLI) ingest $(REAL_DATA) -w $(REAL_DIR)/workspace --format msft-ilc --force
	$(RM_CLI) optimize -w $(REAL_DIR)/workspace
	$(RM_CLI) export-map -w $(REAL_DIR)/workspace
	$(RM_CLI) evaluate -w $(REAL_DIR)/workspace
	$(RM_CLI) report -w $(REAL_DIR)/workspace
	@echo
	@echo "results:"
	@echo "  input (real traces + floor plan, MIT):  $(REAL_DATA)"
	@echo "  workspace:                              $(REAL_DIR)/workspace"
	@echo "  stage reports:                          $(REAL_DIR)/workspace/*/report.json"
	@echo "  aligned walks (TUM files for evo):      $(REAL_DIR)/workspace/optimize/tum/"
	@echo "  the whole map for evo (one TUM file):   $(REAL_DIR)/workspace/map/evo/"
	@echo "  radio map:                              $(REAL_DIR)/workspace/map/"
	@echo "  HTML report:                            $(REAL_DIR)/workspace/report.html"

## make test: ruff + mypy + the pytest suite
test: $(STAMP)
	$(BIN)/ruff check rmbuild tests bench
	$(BIN)/mypy rmbuild
	MPLBACKEND=Agg $(BIN)/python -m pytest -q -x --durations=10

## make bench: benchmarks; figures go to bench/results/*.json and bench/results/SUMMARY.md
bench: $(STAMP)
	MPLBACKEND=Agg $(BIN)/python -m bench.run_all

## make bench-real: ingest -> optimize -> export-map -> evaluate on every real floor with ground truth
## (RMBUILD_DATASETS: the folder holding the full MS ILC 2.0 and IPIN 2023 data sets); bench/results/real.json, real.md.
## Options through BENCH_REAL_ARGS, e.g. BENCH_REAL_ARGS="--floors F1,F4 --out real_after"
bench-real: $(STAMP)
	MPLBACKEND=Agg $(BIN)/python -m bench.bench_real $(BENCH_REAL_ARGS)

## make bench-scan-rate: bench-real on copies of the real floors with fewer Wi-Fi scans (one per 5 s or 10 s,
## Android 9's four per two minutes); bench/results/scan_rate.json and scan_rate.md
bench-scan-rate: $(STAMP)
	MPLBACKEND=Agg $(BIN)/python -m bench.bench_scan_rate

## make fuzz: 10,000 mutated inputs (every format, config, anchors, floor plans, gzip bombs, venues files,
## outputs aimed into a workspace, planted links) under a memory cap, kill -9 / SIGINT fault injection into
## every stage and Dask workers killed during `build`, degraded evidence; figures go to
## bench/results/{fuzz,faults,degraded}.json (FUZZ_CASES, FUZZ_JOBS, FAULT_KILLS, BUILD_KILLS change the size)
FUZZ_CASES ?= 10000
FUZZ_JOBS ?= 2
FAULT_KILLS ?= 25
BUILD_KILLS ?= 20
fuzz: $(STAMP)
	export MPLBACKEND=Agg; \
	$(BIN)/python -m bench.fuzz --cases $(FUZZ_CASES) --jobs $(FUZZ_JOBS) --out bench/results/fuzz.json; a=$$?; \
	$(BIN)/python -m bench.fuzz.faults --kills $(FAULT_KILLS) --build-kills $(BUILD_KILLS) --out bench/results/faults.json; b=$$?; \
	$(BIN)/python -m bench.fuzz.degraded --out bench/results/degraded.json; c=$$?; \
	exit $$(( a | b | c ))

lint: $(STAMP)
	$(BIN)/ruff check rmbuild tests bench
	$(BIN)/mypy rmbuild

clean:
	rm -rf runs .pytest_cache
