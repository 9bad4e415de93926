# Developer entry points. Every target creates .venv with $(PYTHON) when it is missing and
# installs the project editable with the extras it needs; a stamp file inside .venv per set of
# extras makes that a no-op until pyproject.toml changes.

PYTHON ?= python3.11
VENV ?= .venv
BIN := $(VENV)/bin
PIP := $(BIN)/python -m pip

# --no-compile: Python writes a module's bytecode when it is first imported, so only what runs pays
# (a fresh .venv installs in 32 s instead of 71). Quiet progress on CI (no terminal).
PIP_FLAGS := --no-compile
ifdef CI
PIP_FLAGS += --progress-bar off
endif

# Two pytest workers, one test file each at a time (module fixtures built once): the suite is
# JAX-, vLLM- and Ray-bound in turns, so the two cores of the smallest machine both stay busy.
# xdist hands out the files with the most tests first. Handing out the longest first instead
# (--no-loadscope-reorder) was tried from a fresh clone and was not faster.
TEST_WORKERS ?= 2

# Classic Craftax and 20 steps keep the CPU demo to a few minutes; drop them for the paper's setting.
DEMO_FLAGS := --model hf:smollm2-135m --choice loglik --variant classic --limit 6 --max-steps 20 \
	--batch-size 6 --output-dir runs/demo

.PHONY: help setup setup-dev demo test lint bench clean distclean

help:
	@echo "make demo       run a small evaluation with the embedded model (CPU, offline)"
	@echo "make test       lint, type-check and run every test (slow ones included)"
	@echo "make lint       ruff check, ruff format --check, mypy, lint-imports"
	@echo "make bench      run the benchmarks/bench_*.py scripts, one after another"
	@echo "make clean      remove build outputs, caches and runs/demo (keeps the virtualenvs)"
	@echo "make distclean  clean, remove .venv and the .venv-vllm link (not the shared vLLM"
	@echo "                environment it points to: scripts/setup_vllm_cpu.sh --force rebuilds that)"

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(PIP) install $(PIP_FLAGS) --upgrade pip

# Extras hf: the demo. Extras hf,openai,dev: tests, lint, benchmarks.
# An up-to-date dev install already holds the hf extra: no second install then.
$(VENV)/.stamp-hf: pyproject.toml | $(BIN)/python
	@if [ $(VENV)/.stamp-dev -nt pyproject.toml ]; then echo "hf extra present (dev install)"; \
	else $(PIP) install $(PIP_FLAGS) -e ".[hf]"; fi
	touch $@

$(VENV)/.stamp-dev: pyproject.toml | $(BIN)/python
	$(PIP) install $(PIP_FLAGS) -e ".[hf,openai,dev]"
	touch $@

setup: $(VENV)/.stamp-hf
setup-dev: $(VENV)/.stamp-dev

demo: $(VENV)/.stamp-hf
	$(BIN)/craftext-llm eval $(DEMO_FLAGS)

# mypy keeps its cache in the user cache directory, shared by every checkout: it checks each
# file's hash, so a fresh clone re-checks only what differs (45 s -> 1 s on an unchanged tree).
lint: $(VENV)/.stamp-dev
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	MYPY_CACHE_DIR="$${MYPY_CACHE_DIR:-$$($(BIN)/python -c 'from env.downloads import cache_root; print(cache_root() / "mypy")')}" \
		$(BIN)/mypy
	$(BIN)/lint-imports

# --max-worker-restart=0: a worker that crashes (a segfault in native code) stops the run at once,
# naming its test (replacing it under --dist loadfile can leave the run waiting for ever); the tests
# it left unfinished (tests/conftest.py lists them) then run once more in fresh workers, and their
# result is the target's.
# JAX_COMPILATION_CACHE_DIR is not set here: the env enables JAX's persistent cache itself
# (in the user cache directory unless the variable is already set).
# Three jobs side by side, each one's output held back and printed after the tests': the vLLM-on-CPU
# environment's build (its tests wait for it on the script's lock, the other workers go on), lint
# (the workers leave a core idle at times, mypy fills it) and pytest. Any failing fails the target.
test: $(VENV)/.stamp-dev
	@# Debian's Chromium for the browser test of `craftext-llm view` (apt-get, only when missing).
	bash scripts/setup_chromium.sh
	@vllm_log=$$(mktemp); lint_log=$$(mktemp); \
	if [ -f scripts/setup_vllm_cpu.sh ]; then bash scripts/setup_vllm_cpu.sh > "$$vllm_log" 2>&1; \
	else echo "scripts/setup_vllm_cpu.sh not found: skipping the vLLM-on-CPU environment" > "$$vllm_log"; \
	fi & vllm_pid=$$!; \
	$(MAKE) --no-print-directory lint > "$$lint_log" 2>&1 & lint_pid=$$!; \
	unfinished=$$(mktemp); \
	CRAFTEXT_UNFINISHED_TESTS="$$unfinished" $(BIN)/python -m pytest -ra --durations=10 -n $(TEST_WORKERS) \
		--dist loadfile --max-worker-restart=0; tests=$$?; \
	if [ -s "$$unfinished" ]; then \
		echo "== a test worker crashed: the $$(wc -l < "$$unfinished") tests it left unfinished, once more"; \
		$(BIN)/python -m pytest -ra -n $(TEST_WORKERS) --dist loadfile --max-worker-restart=0 "@$$unfinished"; \
		tests=$$?; \
	fi; rm -f "$$unfinished"; \
	wait $$vllm_pid; built=$$?; wait $$lint_pid; linted=$$?; \
	echo "== scripts/setup_vllm_cpu.sh (ran beside the tests): exit $$built"; tail -n 40 "$$vllm_log"; \
	echo "== make lint (ran beside the tests): exit $$linted"; cat "$$lint_log"; rm -f "$$vllm_log" "$$lint_log"; \
	[ $$tests -eq 0 ] && [ $$built -eq 0 ] && [ $$linted -eq 0 ]

# bench_replay_check.py needs a complete run to check: run by hand (docs/benchmarks.md).
bench: $(VENV)/.stamp-dev
	@set -e; for script in benchmarks/bench_*.py; do \
		[ -f "$$script" ] || continue; \
		[ "$$script" = benchmarks/bench_replay_check.py ] && continue; \
		echo "== $$script"; \
		$(BIN)/python "$$script"; \
	done

clean:
	rm -rf build dist *.egg-info .pytest_cache .mypy_cache .ruff_cache .hypothesis runs/demo
	find . -path ./.venv -prune -o -path ./.venv-vllm -prune -o \
		-name __pycache__ -type d -prune -exec rm -rf {} +

# .venv-vllm is a link to the vLLM environment shared by every checkout (in the user cache): rm
# removes the link alone. An older build inside the clone is a real folder, and goes.
distclean: clean
	rm -rf $(VENV) .venv-vllm
