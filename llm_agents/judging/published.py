"""The published numbers a run's report sits beside: the CrafText paper's success rates (zero-shot
LLMs for EASY, its trained agents' Medium totals, none for Hard), BALROG's Crafter leaderboard
rows, and how a run departs from the paper's protocol where that changes the numbers (variant,
dataset splits, step cap, success rule), which decides whether they sit beside it."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict

from env.dataset import OFFICIAL_COMMIT, OFFICIAL_SPLIT_SHA256, PAPER_CATEGORIES
from env.goals import DIFFICULTY_CATEGORIES, Difficulty, ScenarioClass, category_split
from env.rules import SuccessRule
from llm_agents.evaluation.protocol import protocol_for
from llm_agents.judging.rescoring import difficulty_of_run
from llm_agents.run_data.store import RunResults


class PublishedResult(BaseModel):
    """Success rates of one model or agent as the CrafText paper publishes them."""

    model_config = ConfigDict(frozen=True)

    model: str
    """Model or agent name as the paper gives it."""
    rates: dict[str, float]
    """Success rate per goal set (`one`, `combo`, `new_objects` for EASY; `train`,
    `paraphrased`, `new_objects` for Medium, each the total over its scenario classes)."""

    def rate(self, category: str) -> float | None:
        """The published rate of a goal set; None where the paper gives none."""
        return self.rates.get(category)


def _published(model: str, *rates: float, difficulty: Difficulty) -> PublishedResult:
    categories = PAPER_CATEGORIES if difficulty == "easy" else DIFFICULTY_CATEGORIES[difficulty]
    return PublishedResult(model=model, rates=dict(zip(categories, rates, strict=True)))


PUBLISHED: tuple[PublishedResult, ...] = (
    _published("Qwen QwQ-32B", 0.21, 0.10, 0.07, difficulty="easy"),
    _published("Mistral-Small-24B", 0.21, 0.10, 0.09, difficulty="easy"),
    _published("DeepSeek-R1-Distill-Qwen-32B", 0.15, 0.07, 0.06, difficulty="easy"),
)
"""The paper's zero-shot LLM numbers (EASY)."""


PUBLISHED_TRAINED_EASY: tuple[PublishedResult, ...] = (
    _published("PPO-T+", 0.87, 0.70, 0.43, difficulty="easy"),
)
"""The paper's trained plan-conditioned agent on EASY (`one`, `combo`, `new_objects`): what the
leaderboard sets beside the zero-shot rows, never what a zero-shot run's report compares with."""


PUBLISHED_MEDIUM: tuple[PublishedResult, ...] = (
    _published("PPO-T", 0.40, 0.36, 0.22, difficulty="medium"),
    _published("PPO-T+", 0.45, 0.35, 0.28, difficulty="medium"),
    _published("FiLM", 0.43, 0.35, 0.26, difficulty="medium"),
    _published("Dynalang", 0.15, 0.05, 0.10, difficulty="medium"),
)
"""The paper's Medium totals (its Table 2, 50 worlds per instruction), trained agents."""


PUBLISHED_BY_DIFFICULTY: dict[Difficulty, tuple[PublishedResult, ...]] = {
    "easy": PUBLISHED,
    "medium": PUBLISHED_MEDIUM,
    "hard": (),
}


PUBLISHED_KIND: dict[Difficulty, str] = {
    "easy": "zero-shot, EASY split",
    "medium": "the paper's trained agents, Medium totals, 50 worlds per instruction",
    "hard": "none for Hard",
}


#: The paper's Table 2 rows, in its order.
SCENARIO_ROWS: tuple[ScenarioClass, ...] = ("Conditional", "Build", "Localization", "Achievements")


def published_for(difficulty: Difficulty) -> tuple[PublishedResult, ...]:
    """The paper's numbers for runs of `difficulty`."""
    return PUBLISHED_BY_DIFFICULTY[difficulty]


def paper_differences(results: RunResults, rule: SuccessRule) -> list[str]:
    """How a run departs from the paper's protocol of its difficulty where that changes the
    numbers: variant, dataset splits, step cap, answers held to a schema, and the success rule
    it is scored under (`rule`)."""
    config = results.config
    difficulty = difficulty_of_run(results)
    paper = protocol_for("paper", difficulty)
    paper_variant: str = paper.value("variant")
    paper_max_steps: int = paper.value("max_steps")
    paper_rule: SuccessRule = paper.value("success_rule")
    differences = []
    variant = config.get("variant")
    if variant != paper_variant:
        differences.append(f"variant: {variant} Craftax (paper: {paper_variant})")
    digests = results.dataset.get("split_sha256")
    source = f"{results.dataset.get('kind', '?')} {results.dataset.get('path', '?')}"
    if not isinstance(digests, dict):
        differences.append(f"dataset: split digests not recorded (source: {source})")
    else:
        splits = dict.fromkeys(category_split(c, difficulty) for c in paper.value("categories"))
        other = [split for split in splits if digests.get(split) != OFFICIAL_SPLIT_SHA256[split]]
        if other:
            differences.append(
                f"dataset: {', '.join(other)} not the official data at {OFFICIAL_COMMIT[:7]} "
                f"(source: {source})"
            )
    max_steps = config.get("max_steps")
    if max_steps != paper_max_steps:
        differences.append(f"step cap: {max_steps} steps (paper: {paper_max_steps})")
    if config.get("structured_output"):
        differences.append(
            "structured output: every answer held to a JSON schema (paper: free text)"
        )
    if rule != paper_rule:
        differences.append(
            f"success rule: {rule}, a goal completed on the step the game ends counts "
            f"(paper: {paper_rule}, it does not; try --success-rule official)"
        )
    return differences


#: BALROG's Crafter leaderboard (LLM track; balrog-ai/experiments at 989931c), progression %
#: and its standard error over 10 episodes of up to 2,000 steps: its best rows and its
#: smallest models'.
BALROG_PUBLISHED: tuple[tuple[str, float, float], ...] = (
    ("Grok-4", 57.3, 3.9),
    ("Gemini-2.5-Pro", 55.0, 6.0),
    ("GPT-4o", 33.1, 2.3),
    ("Qwen2.5-7B-it", 16.4, 3.0),
    ("Llama-3.2-1B-it", 12.7, 1.9),
)
