"""The agent strategies a run names (`--agent`): each a class the registry maps a name to."""
