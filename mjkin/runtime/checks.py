"""One-line checks of option values (numbers, counts, flags, choices), shared by the library and its envs."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError


def shown(value: Any, limit: int = 80) -> str:
    """``repr(value)`` on one line, cut to ``limit`` characters (for error messages)."""
    text = " ".join(repr(value).split())
    return text if len(text) <= limit else text[:limit - 3] + "..."


def check_number(value: Any, what: str, minimum: float | None = None, strict: bool = False,
                 infinite: bool = False) -> float:
    """``value`` as a float: a real number, not a bool or a string.

    Finite unless ``infinite``, ``>= minimum`` (``>`` if ``strict``).
    """
    bound = "" if minimum is None else f" {'>' if strict else '>='} {minimum:g}"
    is_number = type(value) in (float, int) or (  # the common case first: solve checks options on every call
        not isinstance(value, (bool, np.bool_, str, bytes, list, tuple, dict, set)) and np.ndim(value) == 0
        and np.issubdtype(np.asarray(value).dtype, np.number) and np.isrealobj(value))
    x = float(value) if is_number else np.nan
    if math.isnan(x) or (math.isinf(x) and not infinite) or (minimum is not None and (x <= minimum if strict
                                                                                  else x < minimum)):
        raise InputError(f"{what} must be a {'' if infinite else 'finite '}number{bound}, got {shown(value)}")
    return x


def check_array(value: Any, what: str) -> NDArray[np.float64]:
    """``value`` as a float64 array of any shape: numbers only (text, ragged lists and objects are refused)."""
    try:
        if value is None or isinstance(value, (str, bytes)):  # NumPy reads None as NaN and "1.5" as a number
            raise ValueError
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be numbers (an array of them), got {shown(value, 40)}") from None


def check_vector(value: Any, what: str, n: int = 3) -> NDArray[np.float64]:
    """``value`` as ``n`` finite numbers ``(n,)``: a point, a direction, a range."""
    a = check_array(value, what)
    if a.shape != (n,) or not np.isfinite(a).all():
        raise InputError(f"{what} must be {n} finite numbers, got shape {a.shape}")
    return a


def check_count(value: Any, what: str, least: int = 1, whole_floats: bool = False, most: int | None = None) -> int:
    """``value`` as an int: a whole number ``>= least`` and, if given, ``<= most`` (not a bool; a float only if
    ``whole_floats`` and whole).

    Integers are taken exactly, however large (a seed of 2**64 + 1 stays that).
    """  # noqa: D205
    ok = not isinstance(value, (bool, np.bool_)) and (
        isinstance(value, (int, np.integer))
        or (whole_floats and isinstance(value, (float, np.floating)) and np.isfinite(value) and value == int(value)))
    if not ok or value < least or (most is not None and value > most):
        bound = f">= {least}" if most is None else f"from {least} to {most:,}"
        raise InputError(f"{what} must be a whole number {bound}, got {shown(value)}")
    return int(value)


def check_choice(value: Any, what: str, choices: tuple[str | None, ...]) -> Any:
    """``value`` if it is one of ``choices`` (strings, or None)."""
    if not (value is None or isinstance(value, str)) or value not in choices:
        raise InputError(f"{what} must be {' or '.join(repr(c) for c in choices)}, not {shown(value)}")
    return value


def check_flag(value: Any, what: str) -> bool:
    """``value`` as a bool: True or False only (a string such as 'no' is a mistake, not a truth value)."""
    if not isinstance(value, (bool, np.bool_)):
        raise InputError(f"{what} must be True or False, got {shown(value)}")
    return bool(value)
