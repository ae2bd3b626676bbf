# Two commands on a fresh machine: `make demo` and `make test`. Both set everything up first.
# `make reproduce` runs the paper-scale protocol (hours on 2 cores).
VENV ?= .venv
GL = $$(cat $(VENV)/mujoco-gl 2>/dev/null || echo egl)
RUN = MUJOCO_GL=$(GL) PYOPENGL_PLATFORM=$(GL) $(VENV)/bin/

.PHONY: setup library demo reproduce lint test test-all perf llm-server clean

setup: $(VENV)/.setup-done

$(VENV)/.setup-done: pyproject.toml scripts/setup.sh
	bash scripts/setup.sh $(VENV)

library: setup
	$(RUN)ocplace assets build
	$(RUN)ocplace corpus build

demo: library
	$(RUN)ocplace reproduce --experiment demo --out out/demo

reproduce: library
	$(RUN)ocplace reproduce --experiment default --out out/reproduce

lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/python scripts/check_layers.py

test: library lint
	$(RUN)python -m pytest

test-all: library
	bash scripts/llm_server.sh setup
	$(RUN)python -m pytest -m "slow or not slow"

perf: library
	$(RUN)python perf/scenes.py

# A local OpenAI-compatible LLM for `--parser llm`: SmolLM2-135M on llama.cpp (the first run builds it, 6-20 min).
llm-server:
	bash scripts/llm_server.sh serve $(or $(PORT),8080)

clean:
	rm -rf out .pytest_cache
