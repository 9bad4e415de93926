"""Playing a run: settings and protocols, the episode scheduler and runner (local or on Ray),
the play loop and its sink, the typed view of a recorded run and its replay through the play
loop, and grounding runs."""
