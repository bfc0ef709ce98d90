"""``/v1/stats``: the figures of the dashboard's charts (see :mod:`api.stats`)."""

from __future__ import annotations

import time
from typing import Annotated

from fastapi import APIRouter, Query

from api import stats
from api.deps import AUTH_RESPONSES, OperatorDep
from api.models import ErrorOut, SamplePublic, StatsPublic, WaitingPublic
from api.watch import Sample

router = APIRouter(prefix="/v1", tags=["stats"], responses={
    **AUTH_RESPONSES, 401: {"model": ErrorOut}, 403: {"model": ErrorOut}})


@router.get("/stats", response_model=StatsPublic)
async def fleet_stats(caller: OperatorDep,
                      window_s: Annotated[float, Query(ge=60, le=86_400, description="how far back")] = 3600,
                      bucket_s: Annotated[float, Query(ge=10, le=3600, description="delivery bucket")] = 60,
                      ) -> StatsPublic:
    """Deliveries over time, mail waiting time by priority, coordination latency, battery per drone."""
    now, service = time.time(), caller.service
    store, watch = service.store, service.watch
    battery = [s for series in watch.battery.values() for s in series if s.at > now - window_s]
    coordination = [s for s in watch.coordination if s.at > now - window_s]
    return StatsPublic(
        now=now, bucket_s=bucket_s, deliveries=store.read(lambda c: stats.deliveries(c, now, window_s, bucket_s)),
        waiting=[WaitingPublic(**w.__dict__) for w in store.read(lambda c: stats.waiting(c, now, window_s))],
        coordination_ms=_samples(coordination), battery_pct=_samples(battery))


def _samples(samples: list[Sample]) -> list[SamplePublic]:
    return [SamplePublic(at=round(s.at, 3), drone=s.drone, value=s.value) for s in samples]
