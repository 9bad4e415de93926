"""The LLM side of craftext-llm, in rooms that import only the rooms below them
(docs/architecture.md): the command line, the viewer, planning, evaluation, agents, run data and
backends."""
