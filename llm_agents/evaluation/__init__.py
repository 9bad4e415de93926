"""Evaluating a model: settings and protocols, the episode scheduler and runner (local or
on Ray), the report of a run (published numbers, rescoring, tables, chart, comparison), and
grounding runs and their report."""
