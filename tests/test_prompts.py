"""The template loader: overrides, strict rendering, clear errors; snapshots of the agent's prompts."""

import os
from pathlib import Path

import pytest

from env.errors import UserError
from env.variant import Variant
from llm_agents.agents.strategies.zero_shot import HistoryEntry, ZeroShotAgent
from prompts import (
    PACKAGE_TEMPLATES_DIR,
    load_template,
    render_blocks,
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
    context = {"instruction": "collect wood", "variant": "classic", "actions": []}
    assert render_template("step", context, tmp_path) == "Goal=collect wood"
    assert "Craftax-Classic" in render_template("system", context, tmp_path)
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
        render_template("step", {"instruction": "x", "variant": "full", "actions": []}, tmp_path)
    # Strictness holds for attribute access and loops too, not only plain names.
    (tmp_path / "loop.j2").write_text("{% for a in actions %}{{ a.missing }}{% endfor %}")
    with pytest.raises(UserError, match=r"loop\.j2"):
        render_template("loop", {"actions": [{"name": "NOOP"}]}, tmp_path)


def test_block_templates_give_system_and_user_messages(tmp_path: Path) -> None:
    (tmp_path / "two.j2").write_text(
        "{% block system %} You plan. {% endblock %}{% block user %}Goal: {{ goal }}{% endblock %}"
    )
    messages = render_blocks("two", {"goal": "eat cow"}, tmp_path)
    assert messages == [
        ("system", "You plan."),
        ("user", "Goal: eat cow"),
    ]
    (tmp_path / "flat.j2").write_text("no blocks here")
    with pytest.raises(UserError, match=r"flat\.j2"):
        render_blocks("flat", {}, tmp_path)
    with pytest.raises(UserError, match="goal"):
        render_blocks("two", {}, tmp_path)


# ---------------------------------------------------------------- snapshots of the agent's prompts

SNAPSHOTS = Path(__file__).resolve().parent / "snapshots"
UPDATE_ENV = "UPDATE_SNAPSHOTS"
SNAPSHOT_OBSERVATION = "You face grass.\nA tree is 2 north, 1 west.\nInventory: wood 1."


def agent_prompt(variant: Variant, *, choice_mode: bool, with_plan: bool) -> str:
    agent = ZeroShotAgent(variant, renderer=str, choice_rule="loglik" if choice_mode else None)
    history = [
        HistoryEntry(step=3, action="LEFT", outcome="moved west"),
        HistoryEntry(step=4, action="DO", outcome="gained 1 wood"),
    ]
    context = agent.step_context(
        SNAPSHOT_OBSERVATION,
        "Collect wood and then place a table.",
        plan="1. collect wood\n2. place table" if with_plan else None,
        history=history if with_plan else (),
    )
    user = render_template("step", context)
    return f"=== system ===\n{agent.system_message.content}\n=== user ===\n{user}\n"


SNAPSHOT_CASES = {
    f"{variant.value}_{mode}": (variant, mode == "choice", mode == "plan")
    for variant in Variant
    for mode in ("first_step", "plan", "choice")
}


@pytest.mark.parametrize("case", sorted(SNAPSHOT_CASES))
def test_rendered_prompts_match_snapshots(case: str) -> None:
    variant, choice_mode, with_plan = SNAPSHOT_CASES[case]
    rendered = agent_prompt(variant, choice_mode=choice_mode, with_plan=with_plan)
    path = SNAPSHOTS / f"prompt_{case}.txt"
    if os.environ.get(UPDATE_ENV):
        path.write_text(rendered, encoding="utf-8")
    assert path.is_file(), f"no snapshot {path}; create it with {UPDATE_ENV}=1 pytest {__file__}"
    assert rendered == path.read_text(encoding="utf-8"), (
        f"prompt {case} changed; if intended, regenerate with {UPDATE_ENV}=1"
    )


def test_snapshots_differ_where_the_prompts_must() -> None:
    full = agent_prompt(Variant.FULL, choice_mode=False, with_plan=True)
    classic = agent_prompt(Variant.CLASSIC, choice_mode=False, with_plan=True)
    assert "DESCEND" in full and "DESCEND" not in classic
    assert "step 4: DO: gained 1 wood" in full and "1. collect wood" in full
    assert "ACTION: <NAME>" in full
    assert "ACTION:" not in agent_prompt(Variant.FULL, choice_mode=True, with_plan=False)
