"""The exceptions mjkin raises: one root, one subclass per kind of mistake."""

from __future__ import annotations

from collections.abc import Iterable


class MjkinError(Exception):
    """Root of every error mjkin raises on purpose."""


class ModelError(MjkinError):
    """The model cannot be read or compiled, or lacks what was asked of it."""


class UnknownNameError(MjkinError, KeyError):
    """A body, joint or site name that the model does not have."""

    def __init__(self, kind: str, name: str, known: Iterable[str] | dict[str, Iterable[str]]) -> None:
        groups = known if isinstance(known, dict) else {f"the model's {kind} names": known}
        listing = "; ".join(f"{g}: {', '.join(repr(n) for n in ns) or 'none'}" for g, ns in groups.items())
        super().__init__(f"unknown {kind} {name!r}; {listing}")

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0])

    def __reduce__(self) -> tuple[object, tuple[type, str]]:
        """Pickle by message (the constructor's arguments are not kept), so it crosses processes."""
        return _restore, (type(self), str(self))


def _restore(cls: type[Exception], message: str) -> Exception:
    """An exception of type ``cls`` with ``message``, made without calling its constructor."""
    error = cls.__new__(cls)
    Exception.__init__(error, message)
    return error


class InputError(MjkinError, ValueError):
    """An array argument (q, a target, an option) has the wrong shape or value."""


class GoalError(InputError):
    """A goal is malformed: non-finite target, wrong shape, zero-length direction."""


class MjkinIOError(MjkinError, OSError):
    """A file cannot be read or written."""
