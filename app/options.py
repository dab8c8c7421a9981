"""Argument types of the command line that check values at the edge: a bad value is the
parser's one-line error (`error: coplanar run: argument --seed: ...`, exit code 2)."""

from __future__ import annotations

import argparse
import math
import pathlib

MAX_SEED = 2**63 - 1


def seed(text: str) -> int:
    """A seed: an integer from 0 to 2⁶³ - 1 (numpy's generators take no negative seeds)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"{value} is not a seed (an integer from 0 to 2^63 - 1)")
    return value


def bounded_float(*, low: float, high: float, low_open: bool = False, unit: str = "") -> argparse._ActionType:
    """A finite float in [low, high] (`(low, high]` with `low_open`), as an argparse type."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        inside = (value > low if low_open else value >= low) and value <= high
        if not (math.isfinite(value) and inside):
            left = "(" if low_open else "["
            raise argparse.ArgumentTypeError(f"{text} is outside {left}{low:g}, {high:g}]{unit}")
        return value

    return parse


def path(text: str) -> pathlib.Path:
    """A file or folder path: not empty, no NUL byte (the operating system takes none)."""
    if not text:
        raise argparse.ArgumentTypeError("an empty path")
    if "\x00" in text:
        raise argparse.ArgumentTypeError("a path with a NUL byte")
    return pathlib.Path(text)


def name_or_path(text: str) -> str:
    """A built-in name or a file path (kept as text): not empty, no NUL byte."""
    path(text)
    return text
