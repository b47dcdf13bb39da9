"""mjkin's errors cross process boundaries (multiprocessing, Ray) with their type and message."""

from __future__ import annotations

import pickle

import pytest

import mjkin
from mjkin import errors


def all_errors() -> list[type[errors.MjkinError]]:
    found, todo = [], [errors.MjkinError]
    while todo:
        cls = todo.pop()
        found.append(cls)
        todo.extend(cls.__subclasses__())
    return found


def make(cls: type[errors.MjkinError]) -> errors.MjkinError:
    return cls("joint", "hip", ["knee", "ankle"]) if issubclass(cls, errors.UnknownNameError) else cls("bad input")


@pytest.mark.parametrize("cls", all_errors(), ids=lambda c: c.__name__)
def test_errors_pickle_with_type_and_message(cls):
    error = make(cls)
    back = pickle.loads(pickle.dumps(error))
    assert type(back) is cls and str(back) == str(error)


def test_unknown_name_from_a_tree_round_trips():
    with pytest.raises(mjkin.UnknownNameError) as info:
        mjkin.load("arm7").id("hip", "joint")
    back = pickle.loads(pickle.dumps(info.value))
    assert isinstance(back, KeyError) and str(back) == str(info.value) and "'j1'" in str(back)
