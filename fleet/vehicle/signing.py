"""MAVLink 2 message signing: keys, and a pymavlink codec set up to sign or to check.

A key is 32 bytes, written as 64 hex digits. :func:`read_key_file` reads an agent's key file:
either one key alone (the file of a process that hosts one drone) or a line ``DRONE KEY`` per
drone (one file for a whole fleet: each process takes its own drones' keys). Lines starting
with ``#`` and blank lines are skipped. A key that cannot be used raises
:class:`SigningKeyError`, whose message never quotes the key.

A link that signs sends every message signed and accepts only messages signed with its key,
with a timestamp newer than the last one of their stream (pymavlink's check): an unsigned or
wrongly signed message is dropped as if it never arrived.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from drona_gcs.errors import DronaError

KEY_BYTES = 32
_EPOCH = 1420070400  #: 2015-01-01 UTC, the origin of MAVLink's signing timestamps


class SigningKeyError(DronaError, ValueError):
    """A signing key that cannot be used, or a backend that cannot sign; the message says why."""


def signing_timestamp() -> int:
    """Now, in MAVLink signing units: 10 µs since 2015-01-01."""
    return int((time.time() - _EPOCH) * 100_000)


def parse_key(text: str, where: str = "signing key") -> bytes:
    """A key from its 64 hex digits; SigningKeyError naming ``where`` otherwise."""
    try:
        key = bytes.fromhex(text.strip())
    except ValueError:
        raise SigningKeyError(f"{where}: a signing key is 64 hex digits (32 bytes)") from None
    if len(key) != KEY_BYTES:
        raise SigningKeyError(f"{where}: a signing key is 32 bytes (64 hex digits), got {len(key)} bytes")
    return key


def read_key_file(path: Path, drones: Sequence[str]) -> dict[str, bytes]:
    """Each of ``drones``' key from ``path`` (see the module docstring); SigningKeyError if one is missing."""
    try:
        lines = [line.split() for line in path.read_text(encoding="utf-8").splitlines()]
    except (OSError, UnicodeDecodeError) as exc:
        raise SigningKeyError(f"signing key file {path}: cannot read it: {exc}") from exc
    lines = [words for words in lines if words and not words[0].startswith("#")]
    if len(lines) == 1 and len(lines[0]) == 1:
        if len(drones) != 1:
            raise SigningKeyError(f"signing key file {path} holds one key, for one drone: give each of "
                                  f"{', '.join(drones)} its own line 'DRONE KEY'")
        return {drones[0]: parse_key(lines[0][0], f"signing key file {path}")}
    keys = {}
    for number, words in enumerate(lines, 1):
        if len(words) != 2:
            raise SigningKeyError(f"signing key file {path}: entry {number} is not 'DRONE KEY'")
        keys[words[0]] = parse_key(words[1], f"signing key file {path}, drone {words[0]}")
    missing = [drone for drone in drones if drone not in keys]
    if missing:
        raise SigningKeyError(f"signing key file {path} has no key for {', '.join(missing)}")
    return {drone: keys[drone] for drone in drones}


def sign_outgoing(mav: Any, key: bytes) -> None:
    """``mav`` (a pymavlink MAVLink) signs what it packs from now on."""
    mav.signing.secret_key, mav.signing.link_id = key, 0
    mav.signing.timestamp = signing_timestamp()
    mav.signing.sign_outgoing = True


def stamp_now(mav: Any) -> None:
    """Before packing: a signer's timestamp no older than the clock (pymavlink adds only 1 a message,
    and a vehicle takes a new stream only within a minute of its own time)."""
    mav.signing.timestamp = max(mav.signing.timestamp, signing_timestamp())


def accept_signed_only(mav: Any, key: bytes) -> None:
    """``mav`` decodes only messages signed with ``key`` (any other raises pymavlink's MAVError)."""
    mav.signing.secret_key = key
    mav.signing.timestamp = signing_timestamp()  # a new stream more than a minute older is a replay
    mav.signing.allow_unsigned_callback = _refuse_unsigned


def _refuse_unsigned(mav: Any, msg_id: int) -> bool:
    return False
