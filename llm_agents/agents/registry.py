"""Agent strategy names -> the class that plays each, as `"module:Class"` strings.

Plain data, so the config can check an agent name without importing any agent (they import the
config) and `llm_agents.agents.agent_class` imports only the one a run uses.
"""

AGENTS: dict[str, str] = {
    "zero-shot": "llm_agents.agents.zero_shot:ZeroShotAgent",
    "cot": "llm_agents.agents.cot:ChainOfThoughtAgent",
    "few-shot": "llm_agents.agents.few_shot:FewShotAgent",
    "expert": "llm_agents.agents.expert:ExpertAgent",
}
