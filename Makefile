# hadal — make demo: set up and process the bundled sample dive; make test: set up and run the tests.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
DIVE   ?= data/raw/haidou-challenger-deep
STORE  ?= data/processed
PYTEST_ARGS ?=
# pytest-xdist workers for `make test` (one per core; 0 runs in this process)
TEST_WORKERS ?= auto
export PREFECT_SERVER_ANALYTICS_ENABLED ?= false

.PHONY: setup sysdeps demo test test-integration bench lint clean

setup: $(VENV)/.installed

# open3d needs the system library libusb-1.0 to import; cfchecker (tests) needs UDUNITS-2
sysdeps:
	@if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then \
	  echo "installing libusb-1.0-0 (needed by open3d)"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null; \
	fi
	@if ! ldconfig -p 2>/dev/null | grep -q 'libudunits2.so.0'; then \
	  echo "installing libudunits2-0 (needed by cfchecker, the NCAS CF checker of the integration tests)"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get install -y -qq libudunits2-0 >/dev/null || echo "libudunits2-0 not installed: cfchecks tests skip"; \
	fi

$(VENV)/.installed: pyproject.toml | sysdeps
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	@$(BIN)/python -m pip install -q --upgrade uv
	$(BIN)/uv pip install --python $(BIN)/python -q --compile-bytecode -e '.[test,zarr]'
	@# the numba kernels compiled into their cache now, not by the first run (issue 48: 2.4x its CPU otherwise)
	$(BIN)/hadal compile
	@touch $@

$(DIVE)/dive.yaml: | setup
	$(BIN)/hadal synth $(DIVE)

demo: setup $(DIVE)/dive.yaml
	$(BIN)/hadal run $(DIVE) --store $(STORE)
	@echo "products: $(STORE)/$$(basename $(DIVE))/  (list them: $(BIN)/hadal products $$(basename $(DIVE)) --store $(STORE))"

test: setup
	$(BIN)/python -m pytest -m "not integration" -n $(TEST_WORKERS) $(PYTEST_ARGS)

# the long integration tier (CI runs it after `make test`)
test-integration: setup
	$(BIN)/python -m pytest -m integration $(PYTEST_ARGS)

bench: setup
	@for b in bench/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

lint: setup
	$(BIN)/ruff check src flows tasks tests bench
	$(BIN)/python .ci/mypy-ratchet

clean:
	rm -rf $(VENV) .pytest_cache
