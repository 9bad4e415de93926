"""Secrets kept out of what is recorded, shown or written: the one form in which a model spec,
a URL, a message or a run's settings leave the process.

A secret rides in a URL (its user info, its query values) or in a setting whose name says so
(`api_key`, `token`, `password`, a header): `redact_secrets` stars out the first in any text,
`redact_settings` both in a settings tree (backend options, `extra_body`), so results files,
episodes, step logs, views, cards, exports and logs, which all write settings as recorded, carry
neither. The backend alone is given the values as written.
"""

from __future__ import annotations

import re
from typing import Any
from urllib.parse import urlsplit, urlunsplit

__all__ = ["REDACTED", "is_secret_name", "redact_secrets", "redact_settings", "split_urls"]

#: What a secret is replaced by.
REDACTED = "***"
#: A URL inside a spec or a message: up to the next blank, or the comma before the next URL of
#: a list (a comma inside a URL, a password's included, stays in it).
_URL = re.compile(r"https?://\S+?(?=,\s*https?://|\s|$)")
#: The words of a setting's name that say its value is a secret (`api_key`, `hf_token`,
#: `X-Api-Key`, `Authorization`, `client_secret`, `password`...).
_SECRET_WORDS = frozenset(
    {
        "key",
        "apikey",
        "token",
        "secret",
        "password",
        "passwd",
        "pwd",
        "auth",
        "authorization",
        "credential",
        "credentials",
        "cookie",
        "signature",
        "sig",
    }
)
#: A setting that names where a secret is found (`api_key_env`), not the secret itself.
_NAMES_A_PLACE = ("_env", "_file", "_path")
#: Settings whose every value is a secret whatever its name: HTTP headers.
_HEADERS = frozenset({"headers", "default_headers", "extra_headers", "http_headers"})


def _redact_url(url: str) -> str:
    scheme, _, rest = url.partition("://")
    # Up to the last `@` is user info, even where a password holds a `/` or `@` unencoded: a
    # path with an `@` loses a little more than needed, a password none of itself.
    _userinfo, at, rest = rest.rpartition("@")
    _, netloc, path, query, _fragment = urlsplit(f"{scheme}://{rest}")
    if at:
        netloc = f"{REDACTED}@{netloc}"
    # Every query value goes: which parameter carries a token (`api_key`, `sig`, `code`...) is
    # the server's choice, and none of them changes what a run measures.
    query = "&".join(
        f"{name}={REDACTED}" if sep else name
        for name, sep, _value in (part.partition("=") for part in query.split("&") if part)
    )
    return urlunsplit((scheme, netloc, path, query, ""))


def redact_secrets(text: str) -> str:
    """`text` (a model spec, a URL, a message) with each URL's user info and query values
    replaced by `***` and its fragment dropped: the one form in which a spec is recorded,
    shown or written."""
    return _URL.sub(lambda found: _redact_url(found.group()), text)


def split_urls(text: str) -> list[str]:
    """A comma-separated list of URLs, a comma inside a URL's user info (a password's) kept in
    it: a comma still in a URL's authority (no `/` after its scheme yet), followed by a part
    that is no URL and holds an `@`, joins that part (`http://u:pa,ss@host/v1` is one URL;
    `http://a/v1,b/v1` two, the second to be refused for its missing scheme)."""
    urls: list[str] = []
    for part in text.split(","):
        stripped = part.strip()
        if urls and not stripped.startswith(("http://", "https://")) and "@" in part:
            authority = urls[-1].partition("://")[2]
            if urls[-1].startswith(("http://", "https://")) and "/" not in authority:
                urls[-1] += "," + part
                continue
        urls.append(stripped)
    return urls


def is_secret_name(name: str) -> bool:
    """Whether a setting's name says its value is a secret (`api_key`, `hf_token`, `X-Api-Key`,
    `Authorization`, `password`; not `max_tokens` nor `api_key_env`, which names a variable)."""
    lowered = name.lower()
    if lowered.endswith(_NAMES_A_PLACE):
        return False
    spaced = re.sub(r"([a-z0-9])([A-Z])", r"\1 \2", name).lower()
    words = set(re.split(r"[^a-z0-9]+", spaced)) | {lowered}
    return not _SECRET_WORDS.isdisjoint(words)


def redact_settings(value: Any, *, secret: bool = False) -> Any:
    """A settings tree (mappings, lists, scalars) with every secret starred out: the value of
    each setting whose name says it is one (`is_secret_name`), every header's value, and the
    user info and query values of every URL in a text. Applying it twice changes nothing."""
    if isinstance(value, dict):
        headers = secret
        return {
            key: redact_settings(
                item, secret=headers or (isinstance(key, str) and _is_secret_key(key))
            )
            for key, item in value.items()
        }
    if isinstance(value, list | tuple):
        return type(value)(redact_settings(item, secret=secret) for item in value)
    if secret and value is not None and value != "":
        return REDACTED
    if isinstance(value, str):
        return redact_secrets(value)
    return value


def _is_secret_key(key: str) -> bool:
    return is_secret_name(key) or key.lower() in _HEADERS
