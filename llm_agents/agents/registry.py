"""The built-in agent strategies' names -> the class that plays each, as `"module:Class"`
strings, the entry-point group through which installed packages add names of their own, and the
run settings agents are built from.

Plain data and a protocol, so the config can check an agent name without importing any agent,
agents need nothing from the evaluation room above them, and `llm_agents.agents.agent_class`
(`loading`) imports only the one a run uses.
"""

from typing import Literal, Protocol

from env.goals import Difficulty
from env.variant import Variant
from llm_agents.backends.base import ChoiceRule, ChoiceScoring

AGENTS: dict[str, str] = {
    "zero-shot": "llm_agents.agents.strategies.zero_shot:ZeroShotAgent",
    "cot": "llm_agents.agents.strategies.cot:ChainOfThoughtAgent",
    "few-shot": "llm_agents.agents.strategies.few_shot:FewShotAgent",
    "expert": "llm_agents.agents.strategies.expert:ExpertAgent",
    "guided": "llm_agents.agents.strategies.guided:GuidedAgent",
    "noop": "llm_agents.agents.strategies.noop:NoopAgent",
    "skills": "llm_agents.agents.strategies.skills:SkillsAgent",
}
#: The entry-point group an installed package registers agent names under (name =
#: `package.module:Class`); a name a built-in has is refused.
ENTRY_POINT_GROUP = "craftext_llm.agents"

#: The strategies whose every action is read from the model's answer by `parser.parse_action`
#: (a run of theirs can be checked by parsing its recorded answers again).
PARSED_ANSWER_AGENTS = ("zero-shot", "cot", "few-shot")

#: What the model is shown of the world each step (`--observation`).
ObservationMode = Literal["text", "image", "both"]
#: The strategies whose step message can carry the frames (the others ask no step question of
#: a model, or ask it about the instruction alone).
IMAGE_AGENTS = ("zero-shot", "cot", "few-shot")
#: The strategies whose step message can letter the actions (`--choice-scoring letters`): those
#: that render `step.j2`.
LETTER_AGENTS = ("zero-shot", "few-shot")


class AgentSettings(Protocol):
    """What agents read from a run's settings (`EvalConfig` holds all of it; its docstrings
    say what each setting means). Part of the agent protocol (`protocol.AGENT_PROTOCOL_VERSION`):
    removing a setting here, or changing its meaning, changes the protocol's version."""

    @property
    def agent(self) -> str: ...
    @property
    def variant(self) -> Variant: ...
    @property
    def difficulty(self) -> Difficulty: ...
    @property
    def renderer(self) -> str: ...
    @property
    def choice(self) -> ChoiceRule | None: ...
    @property
    def choice_scoring(self) -> ChoiceScoring: ...
    @property
    def structured_output(self) -> bool: ...
    @property
    def seed(self) -> int: ...
    @property
    def fallback_action(self) -> str: ...
    @property
    def history_length(self) -> int: ...
    @property
    def report_invalid_answers(self) -> bool: ...
    @property
    def observation(self) -> ObservationMode: ...
    @property
    def frame_history(self) -> int: ...
    @property
    def templates_dir(self) -> str | None: ...
    @property
    def cot_steps(self) -> int: ...
    @property
    def cot_max_tokens(self) -> int: ...
    @property
    def few_shot_steps(self) -> int: ...
    @property
    def demos(self) -> str | None: ...
    @property
    def grounding_shots(self) -> int: ...
    @property
    def dataset(self) -> str | None: ...
    @property
    def skill_steps(self) -> int: ...
    @property
    def stuck_after(self) -> int: ...
    @property
    def skill_demos(self) -> int: ...
