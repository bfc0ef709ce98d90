"""The priority mail task planner's requests: the rules on them, and the clearance a
dispatching service gives before mail is taken on board.
"""

from __future__ import annotations

import pytest

from drona_gcs.errors import ProblemError
from drona_gcs.stack.mail import (
    NOT_CLEARED,
    MailPickedUp,
    MailRejected,
    MailStarted,
)
from tests.drona_gcs.stack.mail_helpers import c, goto, mail, planner, request_of


# ======================================================== requests
@pytest.mark.parametrize("priority", [-1, 10, 99])
def test_priority_must_be_0_to_9(priority: int) -> None:
    with pytest.raises(ProblemError, match="priority"):
        mail("m", c(1, 1), c(2, 2), priority)
    for ok in (0, 9):
        assert mail("m", c(1, 1), c(2, 2), ok).priority == ok


def test_pickup_and_dropoff_must_differ() -> None:
    with pytest.raises(ProblemError, match="same cell"):
        mail("m", c(3, 3), c(3, 3))


def test_a_duplicate_assignment_is_ignored() -> None:
    mp = planner()
    m = mail("m", c(2, 2), c(4, 4))
    mp.assign(m)
    mp.assign(m)
    mp.assign(mail("m", c(7, 7), c(8, 8)))  # the id is what counts
    assert mp.queue == [m]
    [started, _] = mp.decide(0, 100, ())
    assert started == MailStarted(m, ())
    mp.assign(m)  # while it is under way
    assert mp.queue == []


# ======================================================== clearance for pickup (a service dispatches)
def test_mail_is_taken_on_board_only_once_its_dispatcher_cleared_it() -> None:
    mp = planner()
    mp.cleared = set()
    m = mail("m", c(2, 2), c(4, 4))
    mp.assign(m)
    goto(mp.decide(0, 100, ()))
    [rejected] = mp.leg_done()  # at the pickup with no clearance: handed back, not on board
    assert rejected == MailRejected(m, NOT_CLEARED, True)
    assert (mp.current, mp.carrying, mp.queue) == (None, False, [])
    mp.assign(m)
    mp.cleared.add("m")
    goto(mp.decide(1, 100, ()))
    assert mp.leg_done() == [MailPickedUp(m)] and mp.carrying


def test_a_clearance_holds_for_one_holding_of_the_mail() -> None:
    """One that comes once the mail was handed back is not taken; one for mail handed back, delivered or
    lost ends with it: given the mail again, the drone waits for a new clearance."""
    mp = planner()
    mp.cleared = set()
    m = mail("m", c(2, 2), c(4, 4))
    assert not mp.clear("m") and mp.cleared == set()  # not held here
    mp.assign(m)
    assert mp.clear("m") and mp.cleared == {"m"}
    mp.reported(MailPickedUp(m))
    assert mp.cleared == {"m"}
    mp.reported(MailRejected(m, "a goal taken", True))
    assert mp.cleared == set()
    no_service = planner()
    no_service.assign(m)
    assert not no_service.clear("m") and no_service.cleared is None


def test_out_of_touch_with_its_dispatcher_a_drone_keeps_only_cleared_mail() -> None:
    mp = planner()
    mp.cleared = {"started"}
    started, waiting, later = mail("started", c(2, 2), c(4, 4), 9), mail("waiting", c(3, 3), c(5, 5)), \
        mail("later", c(1, 1), c(6, 6), 1)
    for m in (started, waiting, later):
        mp.assign(m)
    goto(mp.decide(0, 100, ()))
    assert mp.current == started
    handed = mp.release("out of touch", keep_cleared=True)
    assert [(type(a), request_of(a).id) for a in handed] == [(MailRejected, "waiting"), (MailRejected, "later")]
    assert mp.current == started and mp.queue == []
    assert [request_of(a).id for a in mp.release("lost")] == ["started"]  # without keep_cleared: all not on board
