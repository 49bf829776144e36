"""`permutation`: the one joint alignment by name, and its one error."""

import itertools

import pytest

from torchjfa.data import LogError
from torchjfa.data._joints import permutation

NAMES = ("a", "b", "c", "d")


@pytest.mark.parametrize("order", list(itertools.permutations(NAMES)))
def test_permutation_puts_have_into_want_order(order):
    perm = permutation(order, NAMES)
    assert [order[i] for i in perm] == list(NAMES)
    assert sorted(perm) == list(range(len(NAMES)))


def test_permutation_errors_name_the_joints_that_differ():
    with pytest.raises(ValueError, match=r"log.npz: joint\(s\) \['e'\] are in the log but the "):
        permutation(("a", "b", "e"), ("a", "b", "c"), where="log.npz")
    with pytest.raises(ValueError, match=r"the model's joint\(s\) \['c'\] have no columns in "):
        permutation(("a", "b"), ("a", "b", "c"), want_name="the model")
    with pytest.raises(ValueError, match=r"the log's joints \['b', 'a'\] are not the arm's"):
        permutation(("b", "a"), ("a",), want_name="the arm")
    with pytest.raises(ValueError, match=r"the robot names the joint\(s\) \['a'\] more than once"):
        permutation(("a", "b"), ("a", "a"))
    with pytest.raises(LogError):
        permutation(("a",), ("b",), error=LogError)
