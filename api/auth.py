"""Bearer tokens and roles.

A token has a role: a **submitter** creates mail and reads its own; an **operator**
does everything. Requests without a valid token get 401 (with ``WWW-Authenticate:
Bearer``), requests beyond their role 403. Tokens are looked up by their SHA-256
digest, so the table holds no token in a form that leaks through timing.
"""

from __future__ import annotations

import enum
import hashlib
import re
import secrets
from collections.abc import Iterator
from dataclasses import dataclass

_TOKEN = re.compile(r"[A-Za-z0-9._~+/=-]+")
_NAME = re.compile(r"[A-Za-z0-9._@-]{1,64}")


class Role(enum.Enum):
    SUBMITTER = "submitter"  #: creates mail, reads its own
    OPERATOR = "operator"  #: everything


@dataclass(frozen=True)
class Principal:
    """Who is calling: ``name`` owns the mail it creates."""

    name: str
    role: Role

    @property
    def is_operator(self) -> bool:
        return self.role is Role.OPERATOR


@dataclass(frozen=True)
class TokenEntry:
    secret: str
    role: Role
    name: str

    @property
    def principal(self) -> Principal:
        return Principal(self.name, self.role)


def parse_token_entry(text: str) -> TokenEntry:
    """``ROLE:TOKEN`` or ``ROLE:TOKEN:NAME``; raises ValueError saying what is wrong."""
    parts = text.split(":")
    if len(parts) not in (2, 3):
        raise ValueError(f"token entry {_shown(text)} must be ROLE:TOKEN or ROLE:TOKEN:NAME")
    role_text, secret = parts[0], parts[1]
    try:
        role = Role(role_text)
    except ValueError:
        raise ValueError(f"unknown role {role_text!r}: use operator or submitter") from None
    if not _TOKEN.fullmatch(secret):
        raise ValueError(f"the token of entry {_shown(text)} is empty or has characters other than "
                         "letters, digits and ._~+/=-")
    name = parts[2] if len(parts) == 3 else "tok-" + _digest(secret).hex()[:10]
    if not _NAME.fullmatch(name):
        raise ValueError(f"name {name!r} must be 1-64 letters, digits or ._@-")
    return TokenEntry(secret, role, name)


def make_token() -> str:
    """A fresh random token (for demo mode)."""
    return secrets.token_urlsafe(24)


class TokenTable:
    def __init__(self) -> None:
        self._by_digest: dict[bytes, TokenEntry] = {}

    def add(self, entry: TokenEntry) -> None:
        digest = _digest(entry.secret)
        known = self._by_digest.get(digest)
        if known is not None and known != entry:
            raise ValueError(f"the token of {entry.name} is listed twice with different roles or names")
        self._by_digest[digest] = entry

    def lookup(self, token: str) -> Principal | None:
        entry = self._by_digest.get(_digest(token))
        return entry.principal if entry is not None else None

    def entries(self) -> Iterator[TokenEntry]:
        return iter(self._by_digest.values())

    def __bool__(self) -> bool:
        return bool(self._by_digest)


def _digest(token: str) -> bytes:
    return hashlib.sha256(token.encode()).digest()


def _shown(text: str) -> str:
    """An entry as shown in errors: the role only, never the token."""
    return repr(text.split(":", 1)[0] + ":…") if ":" in text else "(without a colon)"
