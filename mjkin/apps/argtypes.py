"""argparse value types shared by the ``mjkin`` command and its benchmarks: one message for one mistake."""

from __future__ import annotations

import argparse
import math


def _whole(text: str, least: int) -> int:
    """``text`` as an integer >= ``least``, else argparse's error saying the rule."""
    rule = f"a whole number {'> 0' if least == 1 else f'>= {least}'}"
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be {rule}, got {text!r}") from None
    if value < least:
        raise argparse.ArgumentTypeError(f"must be {rule}, got {value}")
    return value


def positive_int(text: str) -> int:
    """An argparse type: an integer > 0."""
    return _whole(text, 1)


def _real(text: str, strict: bool) -> float:
    bound = "> 0" if strict else ">= 0"
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number {bound}, got {text!r}") from None
    if not (math.isfinite(value) and (value > 0 if strict else value >= 0)):
        raise argparse.ArgumentTypeError(f"must be a finite number {bound}, got {text}")
    return value


def positive_float(text: str) -> float:
    """An argparse type: a finite number > 0."""
    return _real(text, True)


def nonnegative_float(text: str) -> float:
    """An argparse type: a finite number >= 0."""
    return _real(text, False)


def distance_or_off(text: str) -> float | None:
    """An argparse type: metres >= 0, or ``off`` (or ``none``) for no such constraint, returned as ``None``."""
    if text.strip().lower() in ("off", "none"):
        return None
    try:
        return _real(text, False)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"must be metres >= 0, or off, got {text!r}") from None


def time_limit(text: str) -> float:
    """An argparse type: seconds > 0, or ``none`` (or 0) for no limit, returned as ``inf``."""
    try:
        value = math.inf if text.strip().lower() == "none" else float(text)
    except ValueError:
        value = math.nan
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"must be seconds > 0, or none (or 0) for no limit, got {text!r}")
    return value or math.inf


def nonnegative_int(text: str) -> int:
    """An argparse type: an integer >= 0 (``--seed``: numpy's generators refuse negative seeds)."""
    return _whole(text, 0)


class Once(argparse.Action):
    """argparse's ``store``, refusing an option given twice (argparse would keep the last silently)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: object,
                 option_string: str | None = None) -> None:
        """Store ``values``; a second use of the option is a usage error naming both values."""
        given: set[str] = namespace.__dict__.setdefault("_given_once", set())
        if self.dest in given:
            raise argparse.ArgumentError(self, f"given twice ({getattr(namespace, self.dest)!r}, then {values!r}); "
                                               "give it once")
        given.add(self.dest)
        setattr(namespace, self.dest, values)
