"""Training data from scored plans, in TRL's conversational format, which its trainers read as
they are: SFT lines `{"messages": [system, user, assistant]}` and DPO lines `{"prompt": [system,
user], "chosen": [assistant], "rejected": [assistant]}`.

The system and user messages are the planner's own request for the instruction (`plan`'s
template), so a model tuned on them is asked the same way `plan` asks it, and the trainer's chat
template is applied to them unchanged. An answer is the plan's steps as numbered lines (what
`plan` reads back), without the headings and notes around them. The caller passes only plans
an export may use (`PlanScore.excluded`: none that break the instruction, are empty, or answer
a text met without acting).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Iterable, Sequence

from llm_agents.planning.checks import parse_plan
from llm_agents.planning.records import PlanScore

Message = dict[str, str]
Prompter = Callable[[str], list[Message]]
"""The planner's request for an instruction, as chat messages (`role`, `content`)."""


def _by_text(scores: Iterable[PlanScore]) -> dict[str, list[PlanScore]]:
    grouped: dict[str, list[PlanScore]] = defaultdict(list)
    for score in scores:
        grouped[score.instruction].append(score)
    return grouped


def _distinct(scores: Sequence[PlanScore]) -> list[PlanScore]:
    """One score per answer (the first), best first, ties to the shorter plan."""
    kept: dict[str, PlanScore] = {}
    for score in scores:
        kept.setdefault(numbered(score.plan), score)
    return sorted(kept.values(), key=rank_key)


def rank_key(score: PlanScore) -> tuple[bool, float, int, int, int]:
    """Sorts a text's candidates best first: a plan no export may use last, then higher
    success, fewer steps, shorter text, earlier candidate."""
    return (
        score.excluded is not None,
        -score.success.rate,
        len(score.steps),
        len(score.plan),
        score.candidate,
    )


def numbered(plan: str) -> str:
    """The plan's steps as `1. ...` lines, what `plan` reads back."""
    steps, _ = parse_plan(plan)
    return "\n".join(f"{number}. {step}" for number, step in enumerate(steps, 1))


def _answer(score: PlanScore) -> list[Message]:
    return [{"role": "assistant", "content": numbered(score.plan)}]


def sft_rows(
    scores: Iterable[PlanScore], threshold: float, prompt: Prompter
) -> list[dict[str, list[Message]]]:
    """Every distinct plan whose success rate is at least `threshold`, as a conversation."""
    rows = []
    for instruction, group in _by_text(scores).items():
        good = [s for s in _distinct(group) if s.success.rate >= threshold]
        rows += [{"messages": prompt(instruction) + _answer(s)} for s in good]
    return rows


def dpo_rows(
    scores: Iterable[PlanScore], margin: float, prompt: Prompter, per_text: int
) -> list[dict[str, list[Message]]]:
    """A text's pairs of distinct plans whose success rates differ by at least `margin`, the
    better one chosen: the widest `per_text`, so no text outweighs the others."""
    rows = []
    for instruction, group in _by_text(scores).items():
        ranked = _distinct(group)
        pairs = [
            (better, worse)
            for i, better in enumerate(ranked)
            for worse in ranked[i + 1 :]
            if better.success.rate - worse.success.rate >= margin
        ]
        pairs.sort(key=lambda pair: pair[1].success.rate - pair[0].success.rate)
        rows += [
            {"prompt": prompt(instruction), "chosen": _answer(b), "rejected": _answer(w)}
            for b, w in pairs[:per_text]
        ]
    return rows
