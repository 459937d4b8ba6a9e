"""Project error classes: every bad input raises one of these with a message a user can act on."""


#: A message quoting what it found (a header, a value) is cut to this many characters in the middle:
#: one readable line, however long the file's line was.
MAX_MESSAGE = 600


def one_line(text, limit=MAX_MESSAGE):
    """``text`` on one line, at most ``limit`` characters (the middle elided)."""
    text = " ".join(str(text).split())
    if len(text) <= limit:
        return text
    keep = (limit - 5) // 2
    return f"{text[:keep]} ... {text[-keep:]}"


class FacecapError(Exception):
    """Base class for readable, expected errors (bad files, bad settings, impossible solves)."""


class InputFileError(FacecapError):
    """A file could not be read. The message names the file and, where known, the line and field."""

    def __init__(self, path, message, *, line=None, field=None):
        self.path = str(path)
        self.line = line
        self.field = field
        where = self.path
        if line is not None:
            where += f", line {line}"
        if field is not None:
            where += f", field '{field}'"
        super().__init__(f"{where}: {one_line(message)}")


class ConfigError(FacecapError):
    """A take config or setting is missing or wrong. The message names the key."""

    def __init__(self, message, *, path=None, key=None):
        self.path = None if path is None else str(path)
        self.key = key
        where = ""
        if path is not None:
            where += f"{path}: "
        if key is not None:
            where += f"[{key}] "
        super().__init__(where + one_line(message))
