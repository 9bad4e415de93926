"""The error type for user mistakes, shared by every package.

The CLI prints a `UserError` as one clear line and exits non-zero; anything else is a bug and
keeps its traceback.
"""


class UserError(Exception):
    """Bad input from the user: a config value, a file, a name that does not exist."""
