"""The skills agent's parts: the catalogue of skills a model may choose, the runner that plays a
chosen skill through the expert's controllers, and worked demonstrations."""
