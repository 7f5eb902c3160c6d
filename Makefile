# mirrorcoach entry points. Every target creates .venv and installs on first use.
PY      ?= python3.11
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
HDM05   ?= $(abspath ../shared/data/hdm05)
OUT     ?= out
# the local cluster's data, logs and pid files (see shared/bus/config.py for every variable)
export MIRRORCOACH_HOME ?= $(CURDIR)/var

.PHONY: install bytecode demo lint test test-quick bench reproduce up down status dashboard clean

$(STAMP): pyproject.toml
	@command -v $(PY) >/dev/null 2>&1 || { echo "error: $(PY) not found (mirrorcoach needs Python 3.11)"; exit 1; }
	@test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	@# compat: a plain path entry; the default editable finder costs every start 18 ms
	$(BIN)/python -m pip install --quiet -e '.[dev]' --config-settings editable_mode=compat
	@touch $(STAMP)

# bytecode of our own modules: where PYTHONDONTWRITEBYTECODE is set (as on our machines), every CLI and service
# start would compile them from source (~50 ms of a one-clip command; every process of the tests)
bytecode: $(STAMP)
	@$(BIN)/python -m compileall -q shared schemas services

install: $(STAMP)

demo: bytecode
	$(BIN)/python -m shared.demo --out $(OUT)/demo

up: bytecode
	$(BIN)/mirrorcoach up

down: $(STAMP)
	$(BIN)/mirrorcoach down

status: $(STAMP)
	-$(BIN)/mirrorcoach status

# style and types, as CI checks them (rules and settings in pyproject.toml)
lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/mypy

test: lint bytecode
	@# CI: Blender is the real client of our BVH files (tests/test_conventions.py), Mesa's Vulkan driver lets the
	@# real rerun viewer run without a screen (tests/test_dashboard.py), espeak-ng says the adverb
	@# (tests/test_capture_stream.py); elsewhere those tests skip, saying why
	@if [ "$$CI" = "true" ] && command -v apt-get >/dev/null 2>&1 && { ! command -v blender >/dev/null 2>&1 || \
	    ! command -v espeak-ng >/dev/null 2>&1 || ! ls /usr/share/vulkan/icd.d/*.json >/dev/null 2>&1; }; then \
	  echo "installing Blender, espeak-ng and Mesa's Vulkan driver (Debian packages) for the BVH, speech and viewer tests"; \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends blender \
	    espeak-ng mesa-vulkan-drivers libvulkan1) >/dev/null 2>&1 || echo "warning: not installed; those tests will be skipped"; fi
	$(BIN)/python -m pytest -q -p no:cacheprovider

# unit, real-data and contract tests: those marked slow (end-to-end clusters, studies, reproductions, the
# real viewer, several hosts, fault injection, benchmarks, anything past ~5 s) are left out
test-quick: bytecode
	$(BIN)/python -m pytest -q -p no:cacheprovider -m "not slow"

bench: bytecode
	$(BIN)/python -m bench.run --hdm05 $(HDM05) --out bench/results
	$(BIN)/python -m bench.recognition --hdm05 $(HDM05) --out bench/results
	$(BIN)/python -m bench.bus --hdm05 $(HDM05) --out bench/results
	$(BIN)/python -m bench.sim --hdm05 $(HDM05) --out bench/results
	$(BIN)/python -m bench.ch3 --hdm05 $(HDM05) --out bench/results
	$(BIN)/python -m bench.questions --out bench/results
	$(BIN)/python -m bench.coach --hdm05 $(HDM05) --out bench/results
	$(BIN)/python -m bench.balance --hdm05 $(HDM05) --out bench/results
	$(BIN)/python -m bench.tracking --hdm05 $(HDM05) --out bench/results
	$(BIN)/python -m bench.emphasis --hdm05 $(HDM05) --out bench/results
	$(BIN)/python -m bench.memory --hdm05 $(HDM05) --out bench/results
	$(BIN)/python -m bench.load --hdm05 $(HDM05) --out bench/results
	$(BIN)/python -m bench.mocap --hdm05 $(HDM05) --out bench/results
	$(BIN)/python -m bench.styles --hdm05 $(HDM05) --out bench/results
	$(BIN)/python -m bench.scale --hdm05 $(HDM05) --out bench/results
	$(BIN)/python -m bench.segmentation --hdm05 $(HDM05) --out bench/results
	$(BIN)/python -m bench.live --hdm05 $(HDM05) --out bench/results
	$(BIN)/python -m bench.fuzz --hdm05 $(HDM05) --out bench/results
	$(BIN)/python -m bench.budget --hdm05 $(HDM05) --out bench/results

reproduce: $(STAMP)
	$(BIN)/mirrorcoach reproduce ch3 ch4 ch5 ch6 --out reports

dashboard: $(STAMP)
	$(BIN)/mirrorcoach dashboard

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache
