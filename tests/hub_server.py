"""A small model hub on loopback, speaking the endpoints `huggingface_hub`'s client uses to
resolve and download a model, so tests run the real client against it (`HF_ENDPOINT`).

- `GET /api/models/{repo}[/revision/{rev}]`: the model info (`HfApi.model_info`): the commit a
  revision is at (`sha`), whether the repository is gated, and its files with their sizes
  (`siblings`, LFS metadata for weights).
- `HEAD|GET /{repo}/resolve/{rev}/{path}`: a file (`hf_hub_download`). A small file answers
  itself, with `X-Repo-Commit`, its git blob `ETag` and `Content-Length`; a weights file
  (LFS on the real hub) answers a redirect to `/cdn/{sha256}` on another host (a second
  server, on 127.0.0.2), with `X-Linked-Etag` and `X-Linked-Size`, as the hub hands downloads
  to its CDN (the client follows only redirects that stay on the hub's host).
- Errors as the hub words them: `X-Error-Code` `RepoNotFound`, `RevisionNotFound`,
  `EntryNotFound`, `GatedRepo` (401 without a token, 403 with one that has no access), and
  401 "Invalid credentials in Authorization header" for a token it does not know.

Branches move (`commit` onto a branch already there), so resolving `main` twice can give two
commits. `claimed_sizes` makes the model info tell a file's size other than its own (a repository
too large for the disk, without writing one).
"""

from __future__ import annotations

import hashlib
import json
import threading
import urllib.parse
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

#: Files the real hub keeps in LFS (and serves from its CDN).
LFS_SUFFIXES = (".safetensors", ".gguf", ".bin")
#: The hub's host and its CDN's: two hosts, as the client tells them apart.
_HOSTS = ("127.0.0.1", "127.0.0.2")
#: The token the server grants gated access to.
GRANTED_TOKEN = "hf_loopbackGrantedToken0123456789"
#: A token the server knows that has no access to gated repositories.
UNGRANTED_TOKEN = "hf_loopbackUngrantedToken012345678"


def git_blob_sha(data: bytes) -> str:
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()


@dataclass
class Repo:
    """One model repository: its commits (each a full set of files) and its branches."""

    commits: dict[str, dict[str, bytes]] = field(default_factory=dict)
    refs: dict[str, str] = field(default_factory=dict)
    gated: bool = False
    claimed_sizes: dict[str, int] = field(default_factory=dict)


@dataclass
class Request:
    method: str
    path: str
    authorization: str | None


class HubServer:
    """The hub (see the module); `url` is what `HF_ENDPOINT` is set to."""

    def __init__(self) -> None:
        self.repos: dict[str, Repo] = {}
        self.requests: list[Request] = []
        self.blobs: dict[str, bytes] = {}
        self._servers = [ThreadingHTTPServer((host, 0), _handler(self)) for host in _HOSTS]
        for server in self._servers:
            server.daemon_threads = True
        self.url, self.cdn_url = (
            f"http://{host}:{server.server_address[1]}"
            for host, server in zip(_HOSTS, self._servers, strict=True)
        )

    def commit(
        self, repo_id: str, files: dict[str, bytes], *, branch: str = "main", gated: bool = False
    ) -> str:
        """Add a commit holding `files` on `branch` (moving it) and return its sha."""
        repo = self.repos.setdefault(repo_id, Repo())
        repo.gated = repo.gated or gated
        digest = hashlib.sha1(repo_id.encode())
        digest.update(repo.refs.get(branch, "").encode())
        for name in sorted(files):
            digest.update(name.encode() + b"\0" + hashlib.sha256(files[name]).digest())
        sha = digest.hexdigest()
        repo.commits[sha] = dict(files)
        repo.refs[branch] = sha
        for data in files.values():
            self.blobs[hashlib.sha256(data).hexdigest()] = data
        return sha

    @contextmanager
    def running(self) -> Iterator[HubServer]:
        threads = [
            threading.Thread(target=server.serve_forever, daemon=True) for server in self._servers
        ]
        for thread in threads:
            thread.start()
        try:
            yield self
        finally:
            for server, thread in zip(self._servers, threads, strict=True):
                server.shutdown()
                server.server_close()
                thread.join()

    def info(self, repo_id: str, sha: str) -> dict[str, object]:
        repo = self.repos[repo_id]
        siblings = []
        for name, data in sorted(repo.commits[sha].items()):
            size = repo.claimed_sizes.get(name, len(data))
            sibling: dict[str, object] = {
                "rfilename": name,
                "size": size,
                "blobId": git_blob_sha(data),
            }
            if name.endswith(LFS_SUFFIXES):
                sibling["lfs"] = {
                    "sha256": hashlib.sha256(data).hexdigest(),
                    "size": size,
                    "pointerSize": 134,
                }
            siblings.append(sibling)
        return {
            "_id": hashlib.sha1(repo_id.encode()).hexdigest()[:24],
            "id": repo_id,
            "modelId": repo_id,
            "sha": sha,
            "private": False,
            "gated": "manual" if repo.gated else False,
            "disabled": False,
            "tags": [],
            "siblings": siblings,
            "lastModified": "2026-01-01T00:00:00.000Z",
            "createdAt": "2026-01-01T00:00:00.000Z",
        }


def _handler(hub: HubServer) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, format: str, *args: object) -> None:
            pass

        def do_GET(self) -> None:
            self._serve(body=True)

        def do_HEAD(self) -> None:
            self._serve(body=False)

        def _serve(self, *, body: bool) -> None:
            path = urllib.parse.urlsplit(self.path).path
            authorization = self.headers.get("Authorization")
            hub.requests.append(Request(self.command, path, authorization))
            token = authorization.removeprefix("Bearer ") if authorization else None
            if token is not None and token not in (GRANTED_TOKEN, UNGRANTED_TOKEN):
                self._error(401, None, "Invalid credentials in Authorization header")
                return
            if path.startswith("/cdn/"):
                data = hub.blobs.get(path.removeprefix("/cdn/"))
                if data is None:
                    self._error(404, None, "no such blob")
                    return
                self._send(200, data if body else b"", {"Content-Length": str(len(data))})
                return
            if path.startswith("/api/models/"):
                self._model_info(urllib.parse.unquote(path.removeprefix("/api/models/")))
                return
            repo_id, resolve, rest = path.strip("/").partition("/resolve/")
            if not resolve:
                self._error(404, None, "not an endpoint of this hub")
                return
            revision, _, filename = urllib.parse.unquote(rest).partition("/")
            self._file(repo_id, revision, filename, token, body)

        def _model_info(self, rest: str) -> None:
            repo_id, _, revision = rest.partition("/revision/")
            repo = hub.repos.get(repo_id)
            if repo is None:
                self._error(404, "RepoNotFound", "Repository not found")
                return
            sha = self._commit(repo, revision or "main")
            if sha is not None:
                self._json(hub.info(repo_id, sha))

        def _file(
            self, repo_id: str, revision: str, filename: str, token: str | None, body: bool
        ) -> None:
            repo = hub.repos.get(repo_id)
            if repo is None:
                self._error(404, "RepoNotFound", "Repository not found")
                return
            if repo.gated and token != GRANTED_TOKEN:
                self._error(
                    403 if token else 401,
                    "GatedRepo",
                    f"Access to model {repo_id} is restricted and you are not in the "
                    "authorized list.",
                )
                return
            sha = self._commit(repo, revision)
            if sha is None:
                return
            data = repo.commits[sha].get(filename)
            if data is None:
                self._error(404, "EntryNotFound", f"{filename} does not exist")
                return
            headers = {"X-Repo-Commit": sha, "ETag": f'"{git_blob_sha(data)}"'}
            if filename.endswith(LFS_SUFFIXES):
                sha256 = hashlib.sha256(data).hexdigest()
                headers |= {
                    "Location": f"{hub.cdn_url}/cdn/{sha256}",
                    "X-Linked-Etag": f'"{sha256}"',
                    "X-Linked-Size": str(len(data)),
                    "Content-Length": "0",
                }
                self._send(302, b"", headers)
                return
            headers["Content-Length"] = str(len(data))
            self._send(200, data if body else b"", headers)

        def _commit(self, repo: Repo, revision: str) -> str | None:
            sha = repo.refs.get(revision) or (revision if revision in repo.commits else None)
            if sha is None:
                self._error(404, "RevisionNotFound", f"Invalid rev id: {revision}")
            return sha

        def _json(self, data: object) -> None:
            encoded = json.dumps(data).encode()
            self._send(
                200,
                encoded,
                {"Content-Type": "application/json", "Content-Length": str(len(encoded))},
            )

        def _error(self, status: int, code: str | None, message: str) -> None:
            encoded = json.dumps({"error": message}).encode()
            headers = {
                "Content-Type": "application/json",
                "Content-Length": str(len(encoded)),
                "X-Error-Message": message,
            }
            if code is not None:
                headers["X-Error-Code"] = code
            self._send(status, encoded if self.command != "HEAD" else b"", headers)

        def _send(self, status: int, data: bytes, headers: dict[str, str]) -> None:
            self.send_response(status)
            for name, value in headers.items():
                self.send_header(name, value)
            self.end_headers()
            if data:
                self.wfile.write(data)

    return Handler
