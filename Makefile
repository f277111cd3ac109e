# spinedrr — the two commands a newcomer needs are `make study` and `make test`.
# Both install the system packages (Embree, OpenCV, clang) first when they are missing.

SHELL := /bin/bash
CARGO ?= cargo
BIN := target/release/spinedrr
OUT ?= out

.PHONY: deps build study demo test bench clean

deps:
	@bash scripts/install-deps.sh

build: deps
	$(CARGO) build --release

# The paper's whole sensitivity study on the built-in L1–L5 phantom, into out/study/.
study: build
	$(BIN) study --out $(OUT)/study
	@echo "report: $(OUT)/study/report.html (and report.md, tables/, figures/)"

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

# The last line is a plain "N passed, N failed" total over every test binary.
test: deps
	$(CARGO) fmt --all -- --check
	$(CARGO) clippy --workspace --all-targets -- -D warnings
	python3 scripts/check_import_cycles.py src
	@mkdir -p target
	set -o pipefail; $(CARGO) test --workspace --lib --bins --tests 2>&1 | tee target/test.log
	@awk '/^test result:/ {p += $$4; f += $$6} END {printf "%d passed, %d failed\n", p, f}' target/test.log

bench: deps
	$(CARGO) bench

clean:
	$(CARGO) clean
	rm -rf $(OUT)
