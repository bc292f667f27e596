"""The one exception type priortrack raises for bad input."""


class PriortrackError(ValueError):
    """Bad input: a malformed file, a wrong shape, an unknown name or key.

    The message names what is at fault (file and line, argument and expected shape)
    so that a user can act on it without reading a traceback.
    """
