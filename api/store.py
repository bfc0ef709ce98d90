"""The mail store: SQLite in WAL mode, one writer thread, group commit.

Durability: a request is acknowledged only after the transaction holding it has
committed (``synchronous=FULL`` by default: the WAL is fsynced at each commit).
To do that a thousand times a second, every write goes through one writer task:
it takes whatever writes are waiting (up to ``max_batch``), applies them in one
``BEGIN IMMEDIATE`` transaction on its own thread, commits once, and only then
resolves each caller's future. Each write runs in a savepoint, so one write that
fails (an illegal transition, an idempotency conflict) is rolled back alone.

A periodic ``wal_checkpoint(TRUNCATE)``, run by the same writer between batches,
keeps the WAL from growing. Reads use a second connection on the event loop's
thread; in WAL mode they never wait for the writer, and they see only committed
data.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import logging
import secrets
import sqlite3
import time
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar

from api.errors import ApiError, IdempotencyConflict, IllegalTransition, MailNotFound, StoreError
from api.lifecycle import Status, check_transition
from api.schema import MIGRATIONS, SCHEMA, migrate, schema_version
from drona_gcs.errors import mapped
from drona_gcs.workspace import Cell

log = logging.getLogger(__name__)
T = TypeVar("T")

_COLUMNS = "seq, id, owner, px, py, pz, dx, dy, dz, priority, note, status, drone, reason, created_at, updated_at"


@dataclass(frozen=True)
class NewMail:
    pickup: Cell
    dropoff: Cell
    priority: int
    note: str
    owner: str
    idem_key: str | None = None

    @property
    def request_hash(self) -> str:
        return hashlib.sha256(repr((self.pickup, self.dropoff, self.priority, self.note)).encode()).hexdigest()


@dataclass(frozen=True)
class MailRecord:
    seq: int  #: arrival order
    id: str
    owner: str
    pickup: Cell
    dropoff: Cell
    priority: int
    note: str
    status: Status
    drone: str | None
    reason: str
    created_at: float
    updated_at: float

    @classmethod
    def from_row(cls, row: Sequence[Any]) -> MailRecord:
        return cls(row[0], row[1], row[2], (row[3], row[4], row[5]), (row[6], row[7], row[8]), row[9], row[10],
                   Status(row[11]), row[12], row[13], row[14], row[15])


@dataclass(frozen=True)
class AuditEntry:
    status: Status
    at: float
    drone: str | None
    reason: str


@dataclass(frozen=True)
class Change:
    """A committed change of one mail: ``before`` is None for a new mail."""

    record: MailRecord
    before: Status | None
    replayed: bool = False  #: an Idempotency-Key seen before: the stored mail, nothing changed


#: Called on the event loop, in commit order, before the writers' callers hear of the commit.
CommitListener = Callable[[Change], None]


@dataclass
class _Op:
    apply: Callable[[sqlite3.Connection], Any]
    future: asyncio.Future[Any]
    kind: Literal["write", "checkpoint"] = "write"
    result: Any = None
    error: BaseException | None = None
    changes: list[Change] = field(default_factory=list)


class Store:
    def __init__(self, path: Path, *, synchronous: str = "FULL", max_batch: int = 1000) -> None:
        self.path = path
        self.max_batch = max_batch
        self.listeners: list[CommitListener] = []
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="drona-sqlite-writer")
        try:
            with sqlite_errors(path):
                self._writer = self._pool.submit(_connect, path, synchronous, True).result()
                self._reader = _connect(path, synchronous, False)
        except StoreError:
            self._pool.shutdown()
            raise
        self._pending: deque[_Op] = deque()
        self._has_pending: asyncio.Event | None = None

    # ----------------------------------------------------------- writer
    async def run(self) -> None:
        """The writer task: commit waiting writes in batches until cancelled, then close."""
        has_pending, pending = self._event(), self._pending
        loop = asyncio.get_running_loop()
        try:
            while True:
                await has_pending.wait()
                batch = [pending.popleft()]
                while batch[0].kind == "write" and pending and pending[0].kind == "write" \
                        and len(batch) < self.max_batch:
                    batch.append(pending.popleft())
                if not pending:
                    has_pending.clear()
                if batch[0].kind == "checkpoint":
                    await loop.run_in_executor(self._pool, self._checkpoint, batch[0])
                else:
                    await self._write(batch, loop)
                self._finish(batch)
        finally:
            while pending:
                op = pending.popleft()
                if not op.future.done():
                    op.future.set_exception(ApiError("the service is shutting down"))
            self.close()

    def close(self) -> None:
        self._reader.close()
        self._pool.submit(self._writer.close).result()
        self._pool.shutdown()

    def _event(self) -> asyncio.Event:
        if self._has_pending is None:
            self._has_pending = asyncio.Event()
        return self._has_pending

    async def _submit(self, apply: Callable[[sqlite3.Connection], Any], kind: Literal["write", "checkpoint"] = "write",
                      ) -> Any:
        future: asyncio.Future[Any] = asyncio.get_running_loop().create_future()
        self._pending.append(_Op(apply, future, kind))
        self._event().set()
        return await future

    def _checkpoint(self, op: _Op) -> None:
        try:
            with sqlite_errors(self.path):
                op.result = op.apply(self._writer)
        except StoreError as exc:
            op.error = exc

    async def _write(self, batch: list[_Op], loop: asyncio.AbstractEventLoop) -> None:
        """One transaction for the batch: staged here, committed (fsynced) on the writer thread.

        The statements take microseconds, so they run on the event loop's thread; only the
        commit, which waits for the disk, goes to the writer thread. That thread then needs
        the GIL once per batch rather than once per statement (a busy loop holds the GIL for
        up to the switch interval, 5 ms, each time another thread wants it back).
        """
        conn = self._writer
        try:
            with sqlite_errors(self.path):
                conn.execute("BEGIN IMMEDIATE")
                for op in batch:
                    conn.execute("SAVEPOINT op")
                    try:
                        op.result = op.apply(conn)
                    except ApiError as exc:
                        op.error, op.result = exc, None
                        conn.execute("ROLLBACK TO op")
                    conn.execute("RELEASE op")
                await loop.run_in_executor(self._pool, conn.execute, "COMMIT")
        except StoreError as exc:
            log.error("write of %d change(s) failed: %s", len(batch), exc)
            with contextlib.suppress(sqlite3.Error):  # the failure already says what went wrong
                if conn.in_transaction:
                    conn.execute("ROLLBACK")
            for op in batch:
                op.error, op.result = exc, None

    def _finish(self, batch: list[_Op]) -> None:
        for op in batch:
            if op.error is None and isinstance(op.result, Change) and not op.result.replayed:
                for listener in self.listeners:
                    listener(op.result)
        for op in batch:
            if op.future.done():  # the caller went away
                continue
            if op.error is not None:
                op.future.set_exception(op.error)
            else:
                op.future.set_result(op.result)

    # ------------------------------------------------------------ writes
    async def create(self, new: NewMail) -> tuple[MailRecord, bool]:
        """Store a new mail, durably. With a known Idempotency-Key: the stored mail, and False."""
        change: Change = await self._submit(lambda conn: _insert(conn, new, time.time()))
        return change.record, not change.replayed

    async def transition(self, mail_id: str, to: Status, *, drone: str | None = None, reason: str = "",
                         only_from: frozenset[Status] | None = None) -> MailRecord:
        """Move a mail to ``to`` (raises IllegalTransition, MailNotFound); ``drone`` None keeps the drone."""
        change: Change = await self._submit(
            lambda conn: _transition(conn, mail_id, to, drone, reason, only_from, time.time()))
        return change.record

    async def checkpoint(self) -> tuple[int, int, int]:
        """``wal_checkpoint(TRUNCATE)``: (busy, WAL frames, frames checkpointed)."""
        row = await self._submit(lambda conn: conn.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchone(),
                                 "checkpoint")
        return int(row[0]), int(row[1]), int(row[2])

    async def write(self, apply: Callable[[sqlite3.Connection], T]) -> T:
        """Run ``apply`` in the writer's next transaction (its own savepoint); its result once committed."""
        result: T = await self._submit(apply)
        return result

    # ------------------------------------------------------------- reads
    def read(self, query: Callable[[sqlite3.Connection], T]) -> T:
        """``query(connection)`` on the read connection (the event loop's thread only): committed data, never
        waiting for the writer. It must fetch all it needs: SQLite's errors are mapped only while it runs."""
        with sqlite_errors(self.path):
            return query(self._reader)

    def get(self, mail_id: str) -> MailRecord | None:
        row = self.read(lambda c: c.execute(f"SELECT {_COLUMNS} FROM mail WHERE id = ?", (mail_id,)).fetchone())
        return MailRecord.from_row(row) if row else None

    def history(self, seq: int) -> list[AuditEntry]:
        rows = self.read(lambda c: c.execute(
            "SELECT status, at, drone, reason FROM audit WHERE mail_seq = ? ORDER BY n", (seq,)).fetchall())
        return [AuditEntry(Status(r[0]), r[1], r[2], r[3]) for r in rows]

    def page(self, *, status: Status | None, owner: str | None, limit: int, before: int | None,
             ) -> list[MailRecord]:
        """Newest first: at most ``limit`` mails with ``seq < before``, of ``status`` and ``owner`` if given."""
        where, args = ["1"], list[Any]()
        for clause, value in (("status = ?", status.value if status else None), ("owner = ?", owner),
                              ("seq < ?", before)):
            if value is not None:
                where.append(clause)
                args.append(value)
        sql = f"SELECT {_COLUMNS} FROM mail WHERE {' AND '.join(where)} ORDER BY seq DESC LIMIT ?"
        return self._records(sql, (*args, limit))

    def waiting(self, limit: int, offset: int = 0) -> list[MailRecord]:
        """Queued mails in dispatch order: most urgent first, oldest first among equals."""
        return self._records(f"SELECT {_COLUMNS} FROM mail WHERE status = 'queued' "
                             "ORDER BY priority DESC, seq LIMIT ? OFFSET ?", (limit, offset))

    def with_status(self, statuses: frozenset[Status]) -> list[MailRecord]:
        marks = ",".join("?" * len(statuses))
        return self._records(f"SELECT {_COLUMNS} FROM mail WHERE status IN ({marks}) ORDER BY seq",
                             [s.value for s in statuses])

    def count(self, status: Status) -> int:
        row = self.read(lambda c: c.execute("SELECT count(*) FROM mail WHERE status = ?", (status.value,)).fetchone())
        return int(row[0])

    def _records(self, sql: str, args: Sequence[Any]) -> list[MailRecord]:
        return [MailRecord.from_row(r) for r in self.read(lambda c: c.execute(sql, args).fetchall())]


def sqlite_errors(path: Path) -> contextlib.AbstractContextManager[None]:
    """SQLite's errors as :class:`StoreError` naming the file: the one place they are mapped."""
    return mapped(sqlite3.Error, StoreError, str(path))


def _connect(path: Path, synchronous: str, writer: bool) -> sqlite3.Connection:
    # The writer's connection is used by the event loop's thread and the writer thread, never at once.
    conn = sqlite3.connect(path, isolation_level=None, check_same_thread=not writer)
    try:
        conn.execute("PRAGMA busy_timeout = 5000")
        if writer:
            _prepare(conn, path)
        conn.execute(f"PRAGMA synchronous = {synchronous}")
    except BaseException:
        conn.close()
        raise
    return conn


def _prepare(conn: sqlite3.Connection, path: Path) -> None:
    """WAL mode, and the schema brought up to date; a database of a newer schema is refused before anything
    is written to it."""
    if (version := schema_version(conn)) > len(MIGRATIONS):
        raise StoreError(f"{path}: its schema is version {version}, newer than this drona-gcs knows "
                         f"({len(MIGRATIONS)}): run the version that wrote it, or a newer one")
    mode = conn.execute("PRAGMA journal_mode = WAL").fetchone()[0]
    if mode != "wal":
        raise StoreError(f"{path}: SQLite refused WAL mode (journal mode is {mode})")
    conn.executescript(SCHEMA)
    migrate(conn)


def _insert(conn: sqlite3.Connection, new: NewMail, now: float) -> Change:
    if new.idem_key is not None:
        row = conn.execute(f"SELECT {_COLUMNS}, request_hash FROM mail WHERE owner = ? AND idem_key = ?",
                           (new.owner, new.idem_key)).fetchone()
        if row is not None:
            if row[-1] != new.request_hash:
                raise IdempotencyConflict(new.idem_key, row[1])
            return Change(MailRecord.from_row(row), Status(row[11]), replayed=True)
    mail_id = "m-" + secrets.token_hex(8)
    cur = conn.execute(
        "INSERT INTO mail (id, owner, idem_key, request_hash, px, py, pz, dx, dy, dz, priority, note, status, "
        "drone, reason, created_at, updated_at) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, 'queued', NULL, '', ?, ?)",
        (mail_id, new.owner, new.idem_key, new.request_hash, *new.pickup, *new.dropoff, new.priority, new.note,
         now, now))
    seq = cur.lastrowid
    assert seq is not None
    conn.execute("INSERT INTO audit (mail_seq, status, at, drone, reason) VALUES (?, 'queued', ?, NULL, '')",
                 (seq, now))
    record = MailRecord(seq, mail_id, new.owner, new.pickup, new.dropoff, new.priority, new.note, Status.QUEUED,
                        None, "", now, now)
    return Change(record, None)


def _transition(conn: sqlite3.Connection, mail_id: str, to: Status, drone: str | None, reason: str,
                only_from: frozenset[Status] | None, now: float) -> Change:
    row = conn.execute(f"SELECT {_COLUMNS} FROM mail WHERE id = ?", (mail_id,)).fetchone()
    if row is None:
        raise MailNotFound(mail_id)
    old = MailRecord.from_row(row)
    check_transition(mail_id, old.status, to)
    if only_from is not None and old.status not in only_from:
        raise IllegalTransition(mail_id, old.status.value, to.value)
    keep = old.drone if drone is None else drone
    new_drone = None if to is Status.QUEUED else keep
    conn.execute("UPDATE mail SET status = ?, drone = ?, reason = ?, updated_at = ? WHERE seq = ?",
                 (to.value, new_drone, reason, now, old.seq))
    conn.execute("INSERT INTO audit (mail_seq, status, at, drone, reason) VALUES (?, ?, ?, ?, ?)",
                 (old.seq, to.value, now, keep, reason))
    record = MailRecord(old.seq, old.id, old.owner, old.pickup, old.dropoff, old.priority, old.note, to,
                        new_drone, reason, old.created_at, now)
    return Change(record, old.status)
