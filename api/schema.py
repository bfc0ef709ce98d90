"""The mail store's SQLite schema, numbered with ``PRAGMA user_version`` and migrated at start.

:data:`SCHEMA` is the first version (0); :data:`MIGRATIONS` take a database from each version to the
next, each in one transaction, keeping every row. :mod:`api.store` runs them when it opens a database.
"""

from __future__ import annotations

import logging
import sqlite3

log = logging.getLogger(__name__)

SCHEMA = """
CREATE TABLE IF NOT EXISTS mail (
    seq INTEGER PRIMARY KEY,
    id TEXT NOT NULL UNIQUE,
    owner TEXT NOT NULL,
    idem_key TEXT,
    request_hash TEXT NOT NULL,
    px INTEGER NOT NULL, py INTEGER NOT NULL, pz INTEGER NOT NULL,
    dx INTEGER NOT NULL, dy INTEGER NOT NULL, dz INTEGER NOT NULL,
    priority INTEGER NOT NULL,
    note TEXT NOT NULL,
    status TEXT NOT NULL,
    drone TEXT,
    reason TEXT NOT NULL,
    created_at REAL NOT NULL,
    updated_at REAL NOT NULL
);
CREATE UNIQUE INDEX IF NOT EXISTS mail_idem ON mail(owner, idem_key) WHERE idem_key IS NOT NULL;
CREATE INDEX IF NOT EXISTS mail_dispatch ON mail(status, priority DESC, seq);
CREATE INDEX IF NOT EXISTS mail_status ON mail(status, seq);
CREATE INDEX IF NOT EXISTS mail_owner ON mail(owner, seq);
CREATE TABLE IF NOT EXISTS audit (
    n INTEGER PRIMARY KEY,
    mail_seq INTEGER NOT NULL REFERENCES mail(seq),
    status TEXT NOT NULL,
    at REAL NOT NULL,
    drone TEXT,
    reason TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS audit_mail ON audit(mail_seq, n);
"""
#: Schema changes, in order: ``MIGRATIONS[i]`` takes a database from ``PRAGMA user_version`` i to i + 1.
#: Run at start, each in one transaction; existing rows are kept.
MIGRATIONS: tuple[str, ...] = (
    # 1: the fleet's alarms and who acknowledged them (api.alarms); deliveries and pickups by time (api.stats).
    """
    CREATE TABLE IF NOT EXISTS alarm (
        n INTEGER PRIMARY KEY,
        drone TEXT NOT NULL,
        kind TEXT NOT NULL,
        text TEXT NOT NULL,
        raised_at REAL NOT NULL,
        cleared_at REAL,
        acked_at REAL,
        acked_by TEXT
    );
    CREATE INDEX IF NOT EXISTS alarm_open ON alarm(cleared_at, drone, kind);
    CREATE INDEX IF NOT EXISTS audit_status_at ON audit(status, at);
    """,
    # 2: the operator's fleet commands, who asked and what the drones answered (api.commands).
    """
    CREATE TABLE IF NOT EXISTS command (
        n INTEGER PRIMARY KEY,
        at REAL NOT NULL,
        by TEXT NOT NULL,
        action TEXT NOT NULL,
        drone TEXT,
        acks TEXT NOT NULL
    );
    """,
)


def migrate(conn: sqlite3.Connection) -> int:
    """Bring the schema up to date (see :data:`MIGRATIONS`); the version it is at now."""
    version = schema_version(conn)
    for target, script in enumerate(MIGRATIONS[version:], version + 1):
        conn.execute("BEGIN IMMEDIATE")
        try:
            for statement in script.split(";"):
                if statement.strip():
                    conn.execute(statement)
            conn.execute(f"PRAGMA user_version = {target}")
        except sqlite3.Error:
            conn.execute("ROLLBACK")
            raise
        conn.execute("COMMIT")
        log.info("schema migrated to version %d", target)
    return max(version, len(MIGRATIONS))


def schema_version(conn: sqlite3.Connection) -> int:
    return int(conn.execute("PRAGMA user_version").fetchone()[0])
