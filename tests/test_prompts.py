"""The template loader: overrides, strict rendering, clear errors; snapshots of the agent's prompts."""

from pathlib import Path

import pytest

from env.errors import UserError
from prompts import (
    PACKAGE_TEMPLATES_DIR,
    load_template,
    render_blocks,
    render_messages,
    render_template,
    template_path,
)


def test_renders_any_package_template_by_name_with_or_without_suffix() -> None:
    with_suffix = render_template("answer_only.j2", {"has_partial_answer": True})
    without = render_template("answer_only", {"has_partial_answer": True})
    other = render_template("answer_only", {"has_partial_answer": False})
    assert with_suffix == without
    assert with_suffix != other
    assert with_suffix == with_suffix.strip()


def test_user_folder_overrides_by_name_and_keeps_the_rest(tmp_path: Path) -> None:
    (tmp_path / "step.j2").write_text("Goal={{ instruction }}\n")
    messages = render_messages(
        {"instruction": "collect wood", "variant": "classic", "actions": []},
        templates_dir=tmp_path,
    )
    assert [m.role for m in messages] == ["system", "user"]
    assert messages[1].content == "Goal=collect wood"
    assert "Craftax-Classic" in messages[0].content
    assert template_path("step", tmp_path) == tmp_path / "step.j2"
    assert template_path("system", tmp_path) == PACKAGE_TEMPLATES_DIR / "system.j2"


def test_user_template_can_include_package_templates(tmp_path: Path) -> None:
    (tmp_path / "wrapper.j2").write_text("[{% include 'answer_only.j2' %}]")
    text = render_template("wrapper", {"has_partial_answer": False}, tmp_path)
    assert text.startswith("[You ran out") and text.endswith("]")


def test_missing_folder_or_template_names_it(tmp_path: Path) -> None:
    missing = tmp_path / "nope"
    with pytest.raises(UserError, match="nope"):
        render_template("step", {}, missing)
    with pytest.raises(UserError, match=r"no_such_template\.j2"):
        load_template("no_such_template", tmp_path)


def test_syntax_error_names_the_file_and_line(tmp_path: Path) -> None:
    (tmp_path / "broken.j2").write_text("line one\n{% if x %}never closed\n")
    with pytest.raises(UserError, match=r"broken\.j2.*line 2"):
        render_template("broken", {"x": True}, tmp_path)


def test_undefined_variable_is_an_error_naming_file_and_variable(tmp_path: Path) -> None:
    (tmp_path / "step.j2").write_text("{{ instruction }} {{ not_given }}")
    with pytest.raises(UserError, match=r"step\.j2.*not_given"):
        render_messages(
            {"instruction": "x", "variant": "full", "actions": []}, templates_dir=tmp_path
        )
    # Strictness holds for attribute access and loops too, not only plain names.
    (tmp_path / "loop.j2").write_text("{% for a in actions %}{{ a.missing }}{% endfor %}")
    with pytest.raises(UserError, match=r"loop\.j2"):
        render_template("loop", {"actions": [{"name": "NOOP"}]}, tmp_path)


def test_block_templates_give_system_and_user_messages(tmp_path: Path) -> None:
    (tmp_path / "two.j2").write_text(
        "{% block system %} You plan. {% endblock %}{% block user %}Goal: {{ goal }}{% endblock %}"
    )
    messages = render_blocks("two", {"goal": "eat cow"}, tmp_path)
    assert [(m.role, m.content) for m in messages] == [
        ("system", "You plan."),
        ("user", "Goal: eat cow"),
    ]
    (tmp_path / "flat.j2").write_text("no blocks here")
    with pytest.raises(UserError, match=r"flat\.j2"):
        render_blocks("flat", {}, tmp_path)
    with pytest.raises(UserError, match="goal"):
        render_blocks("two", {}, tmp_path)
