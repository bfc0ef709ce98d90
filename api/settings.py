"""``ApiSettings``: every setting of the service, from the environment (prefix ``DRONA_API_``) or arguments.

Tokens come from ``DRONA_API_TOKENS`` (entries separated by commas or white space) and/or
the file ``DRONA_API_TOKEN_FILE`` (one entry a line, ``#`` comments). An entry is
``ROLE:TOKEN`` or ``ROLE:TOKEN:NAME`` with ROLE ``operator`` or ``submitter``; NAME
identifies whose mail it is (by default a fingerprint of the token). Outside demo mode
the service refuses to start without a token, or with one shorter than 16 characters.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from api.auth import TokenTable, parse_token_entry
from api.errors import ConfigError

#: Shortest token accepted outside demo mode.
MIN_TOKEN_LENGTH = 16


class ApiSettings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="DRONA_API_", extra="forbid", frozen=True, env_ignore_empty=True)

    db: Path = Field(Path("drona.db"), description="SQLite database file")
    workspace: Path | None = Field(None, description="workspace file the fleet flies in")
    tokens: str = Field("", description="ROLE:TOKEN[:NAME] entries, separated by commas or white space")
    token_file: Path | None = Field(None, description="file of ROLE:TOKEN[:NAME] entries, one a line")
    demo: bool = Field(False, description="demo/dev mode: a token may be short, or made up at start")
    host: str = "127.0.0.1"
    port: int = Field(8000, ge=0, le=65535)
    synchronous: Literal["FULL", "NORMAL"] = Field(
        "FULL", description="SQLite synchronous mode: FULL survives power loss, NORMAL only a crash")
    checkpoint_s: float = Field(5.0, gt=0, description="seconds between WAL checkpoints (TRUNCATE)")
    max_batch: int = Field(1000, ge=1, description="most writes committed in one transaction")
    per_drone: int = Field(2, ge=1, description="most unfinished mails the service hands one drone")
    assign_timeout_s: float = Field(
        10.0, gt=0, description="an assigned mail its drone never mentions for this long is requeued")
    refuse_backoff_s: float = Field(5.0, ge=0, description="a drone that refused a mail is not offered it again "
                                                          "for this long")
    max_rejections: int = Field(3, ge=1, description="a drone that rejected a mail is offered it again after a "
                                "backoff that doubles each time; the mail fails once every drone has rejected "
                                "it this many times")
    sse_ping_s: float = Field(15.0, gt=0, description="seconds between keep-alive comments on /v1/events")
    sse_queue: int = Field(10000, ge=1, description="events buffered for one slow /v1/events client before "
                                                    "it is dropped")
    tile_url: str = Field("", max_length=500, description="the dashboard's base map: a tile URL template with "
                          "{z}, {x} and {y} (a tile server the operators reach); empty: none, the grid alone")
    tile_attribution: str = Field("", max_length=500, description="the base map's attribution, shown under it")

    @model_validator(mode="after")
    def _tokens_usable(self) -> ApiSettings:
        self.token_table()  # parses, so a bad entry or file fails at start-up
        return self

    def token_table(self) -> TokenTable:
        """The tokens of both sources; raises :class:`ConfigError` naming the setting at fault."""
        table = TokenTable()
        entries = [("DRONA_API_TOKENS", e) for e in self.tokens.replace(",", " ").split()]
        if self.token_file is not None:
            entries += _token_file_entries(self.token_file)
        for where, text in entries:
            try:
                table.add(parse_token_entry(text))
            except ValueError as exc:
                raise ConfigError(f"{where}: {exc}") from exc
        if not self.demo:
            if not table:
                raise ConfigError("no API token: set DRONA_API_TOKENS or DRONA_API_TOKEN_FILE "
                                  "(or run in demo mode, which makes one)")
            short = [t.name for t in table.entries() if len(t.secret) < MIN_TOKEN_LENGTH]
            if short:
                raise ConfigError(f"the token of {', '.join(short)} is shorter than {MIN_TOKEN_LENGTH} "
                                  "characters: use a long random token outside demo mode")
        return table


def _token_file_entries(path: Path) -> list[tuple[str, str]]:
    """``(where, entry)`` for each entry of a token file."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"DRONA_API_TOKEN_FILE: cannot read {path}: {exc}") from exc
    stripped = ((i, line.split("#", 1)[0].strip()) for i, line in enumerate(text.splitlines(), 1))
    return [(f"{path}:{i}", line) for i, line in stripped if line]
