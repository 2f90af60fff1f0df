# Two commands: `make demo` and `make test`. Everything else is set up on the way.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
WORKERS := $(shell $(PYTHON) -c 'import os; print(len(os.sched_getaffinity(0)) + 1)' 2>/dev/null || echo auto)

.PHONY: demo test lint bench clean schema system-deps bench-deps

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/compgw demo

# Debian tools the tests use as real peers (command:package); installed when missing and root.
SYSTEM_TOOLS := mbpoll:mbpoll systemd-analyze:systemd chromium:chromium
# and the C byte pump bench/forwarding.py measures the gateway against in the same run
BENCH_TOOLS := socat:socat
system-deps bench-deps:
	@tools="$(if $(filter bench-deps,$@),$(BENCH_TOOLS),$(SYSTEM_TOOLS))"; missing=""; \
	for pair in $$tools; do tool=$${pair%%:*}; pkg=$${pair#*:}; \
	  command -v $$tool >/dev/null || missing="$$missing $$pkg"; done; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "installing$$missing"; apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq$$missing >/dev/null; \
	  else echo "note: missing$$missing: what needs them is skipped"; fi; \
	fi

test: $(STAMP) system-deps
	$(BIN)/ruff check .
	@# compiled once here, not by each of the suite's first few hundred processes at once
	$(BIN)/python -m compileall -q gateway sim tests bench >/dev/null
	@# a worker per core and one more, one BLAS thread each (tests/conftest.py says why): a
	@# third of the suite's time is tests waiting on loopback replies and a laser's real-time
	@# dwells, a core left idle with a worker per core (2 cores: 380 s, with 3 workers 328 s);
	@# the files in tests/conftest.py's order, the longest first; the 15 slowest tests named
	@# at the end, so that every run measures where the suite's time goes
	OPENBLAS_NUM_THREADS=1 $(BIN)/python -m pytest -q -n $(WORKERS) --dist loadfile --no-loadscope-reorder --durations=15

lint: $(STAMP)
	$(BIN)/ruff check .

bench: $(STAMP) bench-deps
	$(BIN)/python bench/engine.py
	$(BIN)/python bench/real_data_loo.py

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache

schema: $(STAMP)
	$(BIN)/python -c "import json; from gateway.config import json_schema; print(json.dumps(json_schema(), indent=2))" > config/schema.json
