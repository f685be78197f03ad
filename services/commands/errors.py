"""The command line's one error type (below every command, so that none imports the CLI module)."""


class UsageError(Exception):
    """A bad flag, path or file: reported as one line on stderr with exit status 2."""
