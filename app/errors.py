"""What the commands report to the user: expected bad input as one line and exit code 2
(DESIGN §8). Its own module, below the commands and the command line that calls them."""

from __future__ import annotations

EXIT_BAD_INPUT = 2


class UsageError(Exception):
    """Expected bad input: reported as one line, exit code 2."""


def one_line(text: object) -> str:
    """`text` as one printable line: control characters, line and paragraph separators
    and undecodable bytes of file names (surrogates) escaped as Python writes them."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in str(text))
