"""Jinja2 prompt templates (the `*.j2` files beside this module) and their loader.

Any template renders through `render_template(name, context)`. A user folder passed as
`templates_dir` overrides templates by file name; the rest still come from this package.
Rendering is strict: an undefined variable is an error, never an empty string. Every
problem with a template (missing, bad syntax, undefined variable) raises `UserError`
naming the file.

`render_blocks(name, context)` renders one template with `{% block system %}` and
`{% block user %}` blocks into (role, text) pairs, which the caller turns into chat messages:
this package knows templates, not backends.
"""

from __future__ import annotations

import hashlib
from collections import ChainMap
from collections.abc import Callable, Iterable, Mapping
from functools import cache
from pathlib import Path
from typing import Any, Literal

import jinja2

from env.errors import UserError

__all__ = [
    "PACKAGE_TEMPLATES_DIR",
    "BlockRole",
    "load_template",
    "render_blocks",
    "render_template",
    "template_digests",
    "template_path",
    "template_renderer",
    "template_source",
]

#: The folder holding the built-in templates.
PACKAGE_TEMPLATES_DIR = Path(__file__).resolve().parent

_SUFFIX = ".j2"

BlockRole = Literal["system", "user"]
"""The chat role a template block renders for."""


def _file_name(name: str) -> str:
    return name if name.endswith(_SUFFIX) else name + _SUFFIX


@cache
def _environment(templates_dir: Path | None) -> jinja2.Environment:
    search_path = [str(PACKAGE_TEMPLATES_DIR)]
    if templates_dir is not None:
        search_path.insert(0, str(templates_dir))
    return jinja2.Environment(
        loader=jinja2.FileSystemLoader(search_path),
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=False,
        autoescape=False,
    )


def _checked_dir(templates_dir: str | Path | None) -> Path | None:
    if templates_dir is None:
        return None
    folder = Path(templates_dir).expanduser().resolve()
    if not folder.is_dir():
        raise UserError(f"templates folder {templates_dir} does not exist or is not a folder")
    return folder


def template_path(name: str, templates_dir: str | Path | None = None) -> Path:
    """The file a template name resolves to: the user's override if present, else ours."""
    folder = _checked_dir(templates_dir)
    file_name = _file_name(name)
    for candidate_dir in (folder, PACKAGE_TEMPLATES_DIR):
        if candidate_dir is not None and (candidate_dir / file_name).is_file():
            return candidate_dir / file_name
    searched = ", ".join(str(d) for d in (folder, PACKAGE_TEMPLATES_DIR) if d is not None)
    raise UserError(f"prompt template {file_name!r} not found (searched {searched})")


def template_source(name: str, templates_dir: str | Path | None = None) -> str:
    """The raw text of the template a name resolves to (for hashing into run records)."""
    return template_path(name, templates_dir).read_text(encoding="utf-8")


def template_digests(
    names: Iterable[str], templates_dir: str | Path | None = None
) -> dict[str, str]:
    """File name -> SHA-256 of the source each name resolves to: what a run's identity holds, so
    a run resumes only with the templates it rendered."""
    return {
        _file_name(name): hashlib.sha256(
            template_source(name, templates_dir).encode("utf-8")
        ).hexdigest()
        for name in names
    }


def load_template(name: str, templates_dir: str | Path | None = None) -> jinja2.Template:
    """Compile a template by name (`step` or `step.j2`); templates_dir files win over ours."""
    path = template_path(name, templates_dir)
    environment = _environment(_checked_dir(templates_dir))
    try:
        template = environment.get_template(path.name)
    except jinja2.TemplateSyntaxError as err:
        where = err.filename or str(path)
        raise UserError(
            f"prompt template {where} has a syntax error at line {err.lineno}: {err.message}"
        ) from err
    if isinstance(template.globals, ChainMap):
        # Jinja keeps a template's globals as a ChainMap over the environment's, which each
        # render walks in Python, twice: half the time of rendering step.j2. The same names
        # in a plain dict cost next to nothing, and nothing changes the environment's globals.
        template.globals = dict(template.globals)
    return template


def _render_error(template: jinja2.Template, err: jinja2.TemplateError) -> UserError:
    if isinstance(err, jinja2.TemplateSyntaxError):
        return UserError(
            f"prompt template {err.filename or template.filename} has a syntax error at line "
            f"{err.lineno}: {err.message}"
        )
    return UserError(f"prompt template {template.filename} failed to render: {err}")


def render_template(
    name: str,
    context: Mapping[str, Any] | None = None,
    templates_dir: str | Path | None = None,
) -> str:
    """Render any template with any variables into text, without surrounding whitespace."""
    return template_renderer(name, templates_dir)(context)


def template_renderer(
    name: str, templates_dir: str | Path | None = None
) -> Callable[[Mapping[str, Any] | None], str]:
    """`render_template` of one template, found and compiled now, not at every call: for a
    template rendered at every step (finding it stats its files each time)."""
    template = load_template(name, templates_dir)

    def render(context: Mapping[str, Any] | None) -> str:
        try:
            return template.render(dict(context or {})).strip()
        except jinja2.TemplateError as err:
            raise _render_error(template, err) from err

    return render


def render_blocks(
    name: str,
    context: Mapping[str, Any],
    templates_dir: str | Path | None = None,
) -> list[tuple[BlockRole, str]]:
    """(role, text) of a template's `system` and `user` blocks, in that order (absent: skipped)."""
    template = load_template(name, templates_dir)
    roles: tuple[BlockRole, ...] = ("system", "user")
    if not any(role in template.blocks for role in roles):
        raise UserError(f"prompt template {template.filename} has no system or user block")
    try:
        jinja_context = template.new_context(dict(context))
        return [
            (role, "".join(template.blocks[role](jinja_context)).strip())
            for role in roles
            if role in template.blocks
        ]
    except jinja2.TemplateError as err:
        raise _render_error(template, err) from err
