"""The errors a user can cause. The CLI turns each into one line on stderr and exit code 1."""

from __future__ import annotations

MAX_MESSAGE_CHARS = 300


def printable(text: str) -> str:
    """``text`` safe for a terminal: control and unprintable characters (binary garbage
    quoted from a log) escaped, one line, at most ``MAX_MESSAGE_CHARS`` characters."""
    if text.isprintable() and len(text) <= MAX_MESSAGE_CHARS:
        return text
    safe = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    return safe if len(safe) <= MAX_MESSAGE_CHARS else safe[:MAX_MESSAGE_CHARS - 1] + "…"


class DynslamError(Exception):
    """Base of every error that is the user's input or environment, not a bug."""


class InputError(DynslamError):
    """Bad input data: names the file and, where there is one, the line."""

    def __init__(self, source: str, message: str, line: int | None = None) -> None:
        self.source = source
        self.line = line
        self.message = message = printable(message)
        where = f"{source}:{line}" if line is not None else source
        super().__init__(f"{where}: {message}")

    def __reduce__(self) -> tuple[type, tuple[str, str, int | None]]:
        return InputError, (self.source, self.message, self.line)  # pickles (read-ahead)


class SeveralTopicsError(InputError):
    """A bag holds several topics of the kind needed and no option chose one: ``process``
    stops with this, ``info`` describes each."""

    def __init__(self, source: str, kind: str, option: str, counts: dict[str, int]) -> None:
        self.kind, self.option, self.counts = kind, option, counts
        listing = ", ".join(f"{t} ({n} messages)" for t, n in sorted(counts.items()))
        super().__init__(source, f"several {kind} topics: {listing}; choose one with {option}")

    def __reduce__(self) -> tuple[type, tuple[str, str, str, dict[str, int]]]:  # type: ignore
        return SeveralTopicsError, (self.source, self.kind, self.option, self.counts)


class ConfigError(DynslamError):
    """A configuration file or option that cannot be used."""


class OutputError(DynslamError):
    """The output cannot be written where asked (exists, not writable, ...)."""


class ScoreError(DynslamError):
    """An evaluation that cannot give a number: too little of the run matched the reference."""
