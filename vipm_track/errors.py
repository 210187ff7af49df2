"""Errors the user can act on: the CLI prints their message (file, frame, field) and exits 2."""


class InputError(ValueError):
    """Bad input: a file, frame, field or option that cannot be used, named in the message."""
