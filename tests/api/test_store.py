"""The SQLite store: WAL, BEGIN IMMEDIATE batches where one bad write fails alone, checkpoints, the audit trail."""

from __future__ import annotations

import asyncio
import sqlite3
from pathlib import Path

import pytest

from api.errors import IdempotencyConflict, IllegalTransition, MailNotFound, StoreError
from api.lifecycle import Status
from api.schema import MIGRATIONS
from api.store import Change, NewMail, Store
from tests.api.conftest import run


def new(owner: str = "ops", key: str | None = None, priority: int = 5) -> NewMail:
    return NewMail((1, 1, 0), (3, 3, 0), priority, "", owner, key)


async def with_store(path: Path, body: object, **kwargs: object) -> None:
    store = Store(path, **kwargs)  # type: ignore[arg-type]
    writer = asyncio.create_task(store.run())
    try:
        await body(store)  # type: ignore[operator]
    finally:
        writer.cancel()
        with pytest.raises(asyncio.CancelledError):
            await writer


def test_the_database_is_in_wal_mode_and_survives_a_reopen(tmp_path: Path) -> None:
    db = tmp_path / "m.db"

    async def first(store: Store) -> None:
        record, created = await store.create(new())
        assert created and record.status is Status.QUEUED

    run(with_store(db, first))
    with sqlite3.connect(db) as conn:
        assert conn.execute("PRAGMA journal_mode").fetchone() == ("wal",)
        assert conn.execute("SELECT count(*) FROM mail").fetchone() == (1,)

    async def second(store: Store) -> None:
        assert store.count(Status.QUEUED) == 1

    run(with_store(db, second))


def test_a_batch_commits_together_and_a_bad_write_fails_alone(tmp_path: Path) -> None:
    changes: list[Change] = []

    async def body(store: Store) -> None:
        store.listeners.append(changes.append)
        first, _ = await store.create(new(key="k"))
        results = await asyncio.gather(
            store.create(new()), store.transition("m-missing", Status.ASSIGNED, drone="d1"),
            store.create(new(key="k", priority=1)), store.transition(first.id, Status.DELIVERED),
            store.transition(first.id, Status.ASSIGNED, drone="d1"), return_exceptions=True)
        assert isinstance(results[1], MailNotFound)
        assert isinstance(results[2], IdempotencyConflict)
        assert isinstance(results[3], IllegalTransition) and "queued: it cannot become delivered" in str(results[3])
        assert results[4].status is Status.ASSIGNED and results[4].drone == "d1"  # type: ignore[union-attr]
        assert store.count(Status.QUEUED) == 1 and store.count(Status.ASSIGNED) == 1
        again, created = await store.create(new(key="k"))
        assert again.id == first.id and not created

    run(with_store(tmp_path / "m.db", body, max_batch=3))
    # listeners heard each committed change once, in order; the replay and the failures not at all
    assert [(c.before, c.record.status) for c in changes] == [
        (None, Status.QUEUED), (None, Status.QUEUED), (Status.QUEUED, Status.ASSIGNED)]


def test_every_transition_is_kept_with_its_time_drone_and_reason(tmp_path: Path) -> None:
    async def body(store: Store) -> None:
        mail, _ = await store.create(new())
        await store.transition(mail.id, Status.ASSIGNED, drone="d1")
        await store.transition(mail.id, Status.QUEUED, reason="drone d1 was lost")
        await store.transition(mail.id, Status.ASSIGNED, drone="d2")
        await store.transition(mail.id, Status.PICKED_UP)
        done = await store.transition(mail.id, Status.DELIVERED)
        assert done.drone == "d2"
        trail = store.history(mail.seq)
        assert [(e.status.value, e.drone, e.reason) for e in trail] == [
            ("queued", None, ""), ("assigned", "d1", ""), ("queued", "d1", "drone d1 was lost"),
            ("assigned", "d2", ""), ("picked_up", "d2", ""), ("delivered", "d2", "")]
        assert [e.at for e in trail] == sorted(e.at for e in trail)

    run(with_store(tmp_path / "m.db", body))


def test_a_checkpoint_truncates_the_wal(tmp_path: Path) -> None:
    db = tmp_path / "m.db"

    async def body(store: Store) -> None:
        await asyncio.gather(*(store.create(new()) for _ in range(300)))
        assert (tmp_path / "m.db-wal").stat().st_size > 0
        busy, frames, done = await store.checkpoint()
        assert busy == 0 and frames == done
        assert (tmp_path / "m.db-wal").stat().st_size == 0
        assert store.count(Status.QUEUED) == 300

    run(with_store(db, body))


def test_pages_and_dispatch_order(tmp_path: Path) -> None:
    async def body(store: Store) -> None:
        made = [(await store.create(new(owner=o, priority=p)))[0] for o, p in
                (("a", 1), ("b", 9), ("a", 9), ("b", 5))]
        assert [r.id for r in store.waiting(10)] == [made[1].id, made[2].id, made[3].id, made[0].id]
        assert [r.id for r in store.page(status=None, owner="a", limit=10, before=None)] == [made[2].id, made[0].id]
        older = store.page(status=None, owner=None, limit=2, before=made[2].seq)
        assert [r.id for r in older] == [made[1].id, made[0].id]

    run(with_store(tmp_path / "m.db", body))


def test_a_failed_write_names_the_file_and_the_store_writes_again_after(tmp_path: Path) -> None:
    db = tmp_path / "m.db"

    async def body(store: Store) -> None:
        store._writer.execute("PRAGMA query_only = ON")  # as a disk gone read-only
        with pytest.raises(StoreError, match=rf"{db}: attempt to write a readonly database") as failed:
            await store.create(new())
        assert isinstance(failed.value.__cause__, sqlite3.Error)
        store._writer.execute("PRAGMA query_only = OFF")
        record, created = await store.create(new())
        assert created and [r.id for r in store.waiting(10)] == [record.id]

    run(with_store(db, body))


def test_a_failed_read_is_a_store_error(tmp_path: Path) -> None:
    async def body(store: Store) -> None:
        store._reader.set_authorizer(lambda *_: sqlite3.SQLITE_DENY)
        with pytest.raises(StoreError, match="not authorized"):
            store.waiting(10)

    run(with_store(tmp_path / "m.db", body))


def test_a_file_that_is_not_a_database_is_refused_by_name(tmp_path: Path) -> None:
    db = tmp_path / "notes.db"
    db.write_text("not a database, but notes worth keeping\n" * 100)
    with pytest.raises(StoreError, match=rf"{db}: file is not a database"):
        Store(db)
    assert db.read_text().startswith("not a database")  # left as it was


def test_a_database_of_a_newer_schema_is_refused(tmp_path: Path) -> None:
    db = tmp_path / "m.db"
    run(with_store(db, lambda store: store.create(new())))
    with sqlite3.connect(db) as conn:
        conn.execute(f"PRAGMA user_version = {len(MIGRATIONS) + 1}")
        conn.execute("DROP INDEX mail_status")  # as a newer version might: it must not come back
    conn.close()
    before = db.read_bytes()
    with pytest.raises(StoreError, match=rf"version {len(MIGRATIONS) + 1}, newer than this drona-gcs knows"):
        Store(db)
    assert db.read_bytes() == before  # refused before anything was written
