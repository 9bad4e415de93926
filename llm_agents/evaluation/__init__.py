"""Evaluating a model: settings and protocols, the episode scheduler and runner (local or
on Ray), and the report of a run."""
