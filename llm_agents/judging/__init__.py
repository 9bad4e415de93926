"""Judging a finished run: its results card and the replay check behind it, asking the model
again, re-scoring, the report's tables and chart, the comparison with published numbers and
between runs, the goals to read a table without, and the exports. It reads a run through the
typed view (`llm_agents.evaluation.run_view`) and plays nothing but the replay."""
