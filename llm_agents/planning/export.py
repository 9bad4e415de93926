"""Training data from scored plans, in the standard (not conversational) format TRL's trainers
read: SFT lines `{"prompt", "completion"}` and DPO lines `{"prompt", "chosen", "rejected"}`.

The prompt is the planner's own request for the instruction (`plan`'s template, its system and
user blocks joined by a blank line, ending in a newline), so a model tuned on it is asked the
same way `plan` asks it. Completions are the plans as numbered lines.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

from env.variant import Variant
from llm_agents.planning.checks import PlanLimits
from llm_agents.planning.loop import planner_messages
from llm_agents.planning.records import PlanScore

Prompter = Callable[[str], str]


def planner_prompt_text(
    instruction: str,
    limits: PlanLimits | None = None,
    variant: Variant = Variant.FULL,
    templates_dir: str | Path | None = None,
) -> str:
    """The planner's request for `instruction` as one prompt string."""
    messages = planner_messages(instruction, limits, variant, templates_dir)
    return "\n\n".join(message.content for message in messages).rstrip() + "\n"


def _by_text(scores: Iterable[PlanScore]) -> dict[str, list[PlanScore]]:
    grouped: dict[str, list[PlanScore]] = defaultdict(list)
    for score in scores:
        grouped[score.instruction].append(score)
    return grouped


def _distinct(scores: Sequence[PlanScore]) -> list[PlanScore]:
    """One score per plan text (the first), best first, ties to the shorter plan."""
    kept: dict[str, PlanScore] = {}
    for score in scores:
        kept.setdefault(score.plan.strip(), score)
    return sorted(kept.values(), key=rank_key)


def rank_key(score: PlanScore) -> tuple[float, int, int, int]:
    """Sorts a text's candidates best first: higher success, then fewer steps, then shorter
    text, then earlier candidate."""
    return (-score.success.rate, len(score.steps), len(score.plan), score.candidate)


def sft_rows(
    scores: Iterable[PlanScore], threshold: float, prompt: Prompter
) -> list[dict[str, str]]:
    """Every distinct plan whose success rate is at least `threshold`."""
    rows = []
    for instruction, group in _by_text(scores).items():
        good = [s for s in _distinct(group) if s.success.rate >= threshold]
        if good:
            text = prompt(instruction)
            rows += [{"prompt": text, "completion": s.plan.strip()} for s in good]
    return rows


def dpo_rows(scores: Iterable[PlanScore], margin: float, prompt: Prompter) -> list[dict[str, str]]:
    """Every pair of a text's distinct plans whose success rates differ by at least `margin`,
    the better one chosen."""
    rows = []
    for instruction, group in _by_text(scores).items():
        ranked = _distinct(group)
        pairs = [
            (better, worse)
            for i, better in enumerate(ranked)
            for worse in ranked[i + 1 :]
            if better.success.rate - worse.success.rate >= margin
        ]
        if pairs:
            text = prompt(instruction)
            rows += [
                {"prompt": text, "chosen": b.plan.strip(), "rejected": w.plan.strip()}
                for b, w in pairs
            ]
    return rows
