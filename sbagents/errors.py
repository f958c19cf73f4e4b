"""The one exception type the CLIs turn into a single ``error: ...`` line and exit code 2."""


class UsageError(ValueError):
    """Bad user input (an unknown name, a malformed file, an unsupported combination).

    The message is one line that says what was wrong and what is accepted.
    """
