"""Errors that the command line turns into one line on stderr and exit code 2."""


class UserInputError(Exception):
    """A mistake in what the user asked for: a missing file, a bad flag value, an unknown SPEC.

    The CLI prints ``str(error)`` on one line and exits with status 2; no traceback.
    """
