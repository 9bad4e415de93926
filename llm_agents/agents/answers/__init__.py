"""Reading a model's answer: the action names and ids, the parser, lettered choices."""
