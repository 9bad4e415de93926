"""The scripted expert's parts: its plan of what to do next, its navigation and the controllers
that play one task each. The `expert` and `guided` strategies and the skills agent use them."""
