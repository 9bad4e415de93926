"""A run directory's contents: step and episode records, their metrics, and the store that
reads and writes them (the one format every other room shares)."""
