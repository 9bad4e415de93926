"""Reading a plan's steps from a model's answer and checking them against the limits."""

from __future__ import annotations

import re
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from env.variant import Variant
from llm_agents.planning.vocabulary import unknown_words

_STEP_LINE = re.compile(r"^\s*(?:step\s*)?(\d+)\s*[.):]\s*(.*?)\s*$", re.IGNORECASE)
_BULLET_LINE = re.compile(r"^\s*[-*\u2022]\s+(.*?)\s*$")


class PlanLimits(BaseModel):
    """How short a plan must be."""

    model_config = ConfigDict(extra="forbid", frozen=True, use_attribute_docstrings=True)

    max_steps: int = Field(5, ge=1)
    """Most numbered steps a plan may have."""
    max_step_words: int = Field(8, ge=1)
    """Most words one step may have."""


IssueKind = Literal["no_steps", "too_many_steps", "step_too_long", "unknown_words"]


class PlanIssue(BaseModel):
    """One way a plan breaks the rules."""

    model_config = ConfigDict(frozen=True)

    kind: IssueKind
    """What is wrong: no steps, too many steps, a step too long, or words unknown to Craftax."""
    detail: str
    """A human-readable explanation, also shown to the model in the repair request."""


class PlanCheck(BaseModel):
    """A plan parsed into steps and checked against the limits and the Craftax vocabulary."""

    steps: list[str]
    """The step texts, without their numbers."""
    extra_lines: list[str]
    """Lines that are neither steps nor a heading such as "Plan:"; dropped from the kept plan."""
    unknown: list[str]
    """Words that are neither Craftax names nor common words, in order of first use."""
    issues: list[PlanIssue]
    """Every rule the plan breaks; empty for a valid plan."""

    @property
    def ok(self) -> bool:
        return not self.issues

    @property
    def text(self) -> str:
        """The plan as numbered lines, the format of CrafText's plan file."""
        return "\n".join(f"{i}. {step}" for i, step in enumerate(self.steps, 1))


PlanStatus = Literal["valid", "repaired", "failed"]


def parse_plan(text: str) -> tuple[list[str], list[str]]:
    """Split a plan into step texts and leftover lines.

    Steps are numbered lines ("1. x", "2) x", "Step 3: x"); if there are none, bulleted lines
    count as steps. Headings (a short line ending in a colon, such as "Plan:") are dropped.
    """
    steps: list[str] = []
    bullets: list[str] = []
    extra: list[str] = []
    for line in text.splitlines():
        stripped = line.strip().strip("*_").strip()
        if not stripped:
            continue
        if numbered := _STEP_LINE.match(stripped):
            if numbered.group(2):
                steps.append(numbered.group(2))
        elif bulleted := _BULLET_LINE.match(stripped):
            bullets.append(bulleted.group(1))
        elif not (stripped.endswith(":") and len(stripped.split()) <= 6):
            extra.append(stripped)
    if not steps:
        steps = bullets
    else:
        extra += bullets
    return steps, extra


def check_plan(
    text: str, limits: PlanLimits | None = None, variant: Variant = Variant.FULL
) -> PlanCheck:
    """Parse a plan and list every rule it breaks."""
    limits = limits or PlanLimits()
    steps, extra = parse_plan(text)
    issues: list[PlanIssue] = []
    if not steps:
        issues.append(PlanIssue(kind="no_steps", detail="the answer has no numbered steps"))
    if len(steps) > limits.max_steps:
        issues.append(
            PlanIssue(
                kind="too_many_steps",
                detail=f"{len(steps)} steps; at most {limits.max_steps} are allowed",
            )
        )
    for number, step in enumerate(steps, 1):
        if (words := len(step.split())) > limits.max_step_words:
            issues.append(
                PlanIssue(
                    kind="step_too_long",
                    detail=f"step {number} has {words} words; at most {limits.max_step_words} are allowed",
                )
            )
    unknown = unknown_words("\n".join(steps), variant)
    if unknown:
        issues.append(
            PlanIssue(
                kind="unknown_words",
                detail=f"words that name nothing in Craftax: {', '.join(unknown)}",
            )
        )
    return PlanCheck(steps=steps, extra_lines=extra, unknown=unknown, issues=issues)
