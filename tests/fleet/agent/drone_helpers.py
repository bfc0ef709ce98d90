"""Shared helpers of the drone agent's tests (``test_drone*.py``): its workspace, frame, keys and
a scripted vehicle over its start.
"""

from __future__ import annotations

from drona_gcs.geo import GeoFrame
from drona_gcs.workspace import Workspace
from fleet.transport.keys import FleetKeys
from fleet.transport.wire import MailStatus, MailStatusReport
from tests.fakes.node import FakeNode
from tests.fakes.vehicle import FakeVehicle

#: With a parking cell: an idle drone that may plan flies there (a drone that is down must not).
WS = Workspace.build(size=(8, 8, 1), cell_size_m=2.0, tau_s=1.0, drones={"d1": (0, 0, 0)}, parking=((7, 7, 0),))
FRAME = GeoFrame(WS)
KEYS = FleetKeys("t")


def statuses(node: FakeNode, mail_id: str) -> list[tuple[MailStatus, str]]:
    """What d1 reported of mail ``mail_id``, in order."""
    return [(r.status, r.reason) for r in node.bodies(KEYS.status("d1", mail_id)) if isinstance(r, MailStatusReport)]


def vehicle_over_its_start() -> FakeVehicle:
    """d1's vehicle, ready, armed and in the air over (0, 0, 0) of the 8 x 8 workspace."""
    return FakeVehicle(FRAME, (0, 0, 0))
