"""Plans for instructions (the input of plan-conditioned agents): prompting a model for them
(`loop`), checking them (`checks`, `vocabulary`) and the journal they are saved through."""

from llm_agents.planning.checks import PlanCheck, PlanIssue, PlanLimits, check_plan, parse_plan
from llm_agents.planning.journal import PlanRecord
from llm_agents.planning.loop import (
    PlannerConfig,
    PlanSummary,
    goal_instructions,
    plan_instructions,
    planned_instructions,
    run_planner,
)
from llm_agents.planning.vocabulary import craftax_vocabulary, is_known, unknown_words, word_tokens
from llm_agents.run_data.plans import load_plans

__all__ = [
    "PlanCheck",
    "PlanIssue",
    "PlanLimits",
    "PlanRecord",
    "PlanSummary",
    "PlannerConfig",
    "check_plan",
    "craftax_vocabulary",
    "goal_instructions",
    "is_known",
    "load_plans",
    "parse_plan",
    "plan_instructions",
    "planned_instructions",
    "run_planner",
    "unknown_words",
    "word_tokens",
]
