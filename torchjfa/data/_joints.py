"""Joint alignment by name: the one place that matches one list of joints to another.

Logs, trajectories, MuJoCo models and identified models each list their joints in their own
order; `permutation` gives the column order that puts one list in the other's order, and
raises one error, naming the joints that do not match, when the two are not the same joints.
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = ["permutation"]


def permutation(
    have: Sequence[str],
    want: Sequence[str],
    *,
    where: str = "",
    have_name: str = "the log",
    want_name: str = "the robot",
    error: type[ValueError] = ValueError,
) -> list[int]:
    """Indices ``perm`` with ``have[perm[i]] == want[i]``: ``x[:, perm]`` puts columns in
    ``have`` order into ``want`` order.

    Args:
        have: ``(n_dof,)`` joint names of the data to reorder.
        want: ``(n_dof,)`` joint names in the order wanted (e.g. a model's ``joint_names``).
        where: what the data is (a file name), put in front of the message.
        have_name: what ``have`` belongs to, for the message (``"the log"``).
        want_name: what ``want`` belongs to, for the message (``"the robot"``).
        error: the `ValueError` subclass to raise (e.g. `torchjfa.data.LogError`).

    Returns:
        ``n_dof`` indices into ``have``.

    Raises:
        ValueError (``error``): if a list repeats a name or the two are not the same joints.
    """
    have = tuple(str(j) for j in have)
    want = tuple(str(j) for j in want)
    prefix = f"{where}: " if where else ""
    for names, owner in ((have, have_name), (want, want_name)):
        repeated = sorted({j for j in names if names.count(j) > 1})
        if repeated:
            raise error(f"{prefix}{owner} names the joint(s) {repeated} more than once")
    extra = [j for j in have if j not in want]
    missing = [j for j in want if j not in have]
    if extra or missing:
        if extra:
            what = f"joint(s) {extra} are in {have_name} but {want_name} has no joint of that name"
        else:
            what = f"{want_name}'s joint(s) {missing} have no columns in {have_name}"
        raise error(
            f"{prefix}{what}; {have_name}'s joints {list(have)} are not {want_name}'s "
            f"{list(want)} (rename them to match)"
        )
    return [have.index(j) for j in want]
