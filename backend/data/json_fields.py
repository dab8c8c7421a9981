"""Typed fields of scene JSON objects: each reader returns the value or raises ValueError
with a short reason naming the field (`where.key: expected 3 numbers`), which the scene
loader turns into one line naming the file."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def vector(obj: dict[str, Any], key: str, n: int, where: str) -> np.ndarray:
    """`obj[key]` as (n,) floats: a list of n numbers."""
    if key not in obj:
        raise ValueError(f"{where}: missing {key!r}")
    value = obj[key]
    if not (isinstance(value, list) and len(value) == n and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in value)):
        raise ValueError(f"{where}.{key}: expected {n} numbers")
    return np.array(value, dtype=float)


def number(obj: dict[str, Any], key: str, where: str, default: float | None = None) -> float:
    """`obj[key]` as a float (`default` when absent; required when None)."""
    if key not in obj:
        if default is None:
            raise ValueError(f"{where}: missing {key!r}")
        return default
    value = obj[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}.{key}: expected a number")
    return float(value)


def bounded(obj: dict[str, Any], key: str, where: str, *, low: float, high: float, low_open: bool = False, default: float | None = None) -> float:
    """`obj[key]` as a finite float in [low, high] (or (low, high] when `low_open`)."""
    value = number(obj, key, where, default)
    if not (math.isfinite(value) and (value > low if low_open else value >= low) and value <= high):
        raise ValueError(f"{where}.{key}: expected a number in {'(' if low_open else '['}{low:g}, {high:g}]")
    return value


def integer(obj: dict[str, Any], key: str, where: str, default: int | None = None) -> int:
    """`obj[key]` as an int (`default` when absent; required when None)."""
    if key not in obj:
        if default is None:
            raise ValueError(f"{where}: missing {key!r}")
        return default
    value = obj[key]
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{where}.{key}: expected an integer")
    return value


def optional_object(obj: dict[str, Any], key: str, where: str) -> dict[str, Any] | None:
    """`obj[key]` when it is an object, None when absent or null; ValueError otherwise."""
    value = obj.get(key)
    if value is not None and not isinstance(value, dict):
        raise ValueError(f"{where}.{key}: expected an object or null")
    return value


def objects(data: dict[str, Any], key: str) -> list[dict[str, Any]]:
    """`data[key]` as a list of objects (empty when absent)."""
    items = data.get(key, [])
    if not isinstance(items, list) or not all(isinstance(x, dict) for x in items):
        raise ValueError(f"{key}: expected a list of objects")
    return items
