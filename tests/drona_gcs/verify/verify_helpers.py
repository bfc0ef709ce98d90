"""Shared helpers of the systematic tester's tests.
"""

from __future__ import annotations

from typing import TypedDict


class Needs(TypedDict, total=False):
    """The faults of a :class:`Scenario` a bug needs."""

    partitions: int
    skews: int


#: The fault that makes a bug show (none but for these).
NEEDS: dict[str, Needs] = {"fly-unheld": {"partitions": 1}, "pickup-uncleared": {"partitions": 1},
                           "skew-blind": {"skews": 1}}
