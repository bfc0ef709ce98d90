"""Tokens and roles: settings refuse to run without a usable token; 401, 403, and submitters see their own."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from api.auth import Role, parse_token_entry
from api.errors import ConfigError
from api.settings import ApiSettings
from drona_gcs.workspace import Workspace
from tests.api.conftest import OPERATOR, OTHER_SUBMITTER, SUBMITTER, api_settings, auth, run, running


def test_token_entries_parse_with_role_and_owner() -> None:
    entry = parse_token_entry("submitter:abcdefghijklmnopqrst:alice")
    assert (entry.role, entry.name, entry.secret) == (Role.SUBMITTER, "alice", "abcdefghijklmnopqrst")
    anonymous = parse_token_entry("operator:abcdefghijklmnopqrst")
    assert anonymous.name.startswith("tok-") and "abcdef" not in anonymous.name  # a fingerprint, not the token
    for bad, why in (("admin:abcdefghijklmnopqrst", "unknown role 'admin'"), ("operator", "ROLE:TOKEN"),
                     ("operator:bad token here!", "characters"), ("operator:abcdefghijklmnopq:no spaces", "name")):
        with pytest.raises(ValueError, match=why):
            parse_token_entry(bad)


def test_settings_refuse_to_start_without_a_token_unless_in_demo_mode(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("DRONA_API_TOKENS", raising=False)
    with pytest.raises(ConfigError, match="no API token: set DRONA_API_TOKENS or DRONA_API_TOKEN_FILE"):
        api_settings()
    with pytest.raises(ConfigError, match="shorter than 16 characters"):
        api_settings(tokens="operator:changeme")
    assert not api_settings(demo=True).token_table()
    assert api_settings(demo=True, tokens="operator:demo").token_table().lookup("demo") is not None


def test_settings_come_from_the_environment(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("DRONA_API_TOKENS", f"operator:{OPERATOR},submitter:{SUBMITTER}:alice")
    monkeypatch.setenv("DRONA_API_DB", str(tmp_path / "x.db"))
    monkeypatch.setenv("DRONA_API_PER_DRONE", "3")
    settings = api_settings()
    assert settings.db == tmp_path / "x.db" and settings.per_drone == 3
    principal = settings.token_table().lookup(SUBMITTER)
    assert principal is not None and principal.name == "alice" and principal.role is Role.SUBMITTER
    monkeypatch.setenv("DRONA_API_PER_DRONE", "0")
    with pytest.raises(ValidationError, match="per_drone"):
        api_settings()


def test_a_token_file_names_the_line_at_fault(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("DRONA_API_TOKENS", raising=False)
    good = tmp_path / "tokens"
    good.write_text(f"# operators\noperator:{OPERATOR}:ops\n\nsubmitter:{SUBMITTER}  # alice's\n")
    table = api_settings(token_file=good).token_table()
    assert table.lookup(OPERATOR) is not None and table.lookup(SUBMITTER) is not None
    bad = tmp_path / "bad"
    bad.write_text(f"operator:{OPERATOR}\nboss:{SUBMITTER}\n")
    with pytest.raises(ConfigError, match=rf"{bad}:2: unknown role 'boss'"):
        api_settings(token_file=bad)
    with pytest.raises(ConfigError, match="cannot read"):
        api_settings(token_file=tmp_path / "missing")


def test_401_without_or_with_an_unknown_token(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            for headers in ({}, {"Authorization": "Bearer wrong-token-0123456789"}, {"Authorization": OPERATOR},
                            {"Authorization": "Basic b3A6cHc="}):
                for method, path in (("GET", "/v1/mail"), ("POST", "/v1/mail"), ("GET", "/v1/fleet"),
                                     ("GET", "/v1/workspace"), ("GET", "/v1/mail/m-1")):
                    res = await h.client.request(method, path, headers=headers, json={})
                    assert res.status_code == 401, (method, path, headers)
                    assert res.headers["WWW-Authenticate"].startswith("Bearer")
            assert (await h.client.get("/healthz")).status_code == 200

    run(body())


def test_a_submitter_creates_and_reads_only_its_own(settings: ApiSettings, workspace: Workspace) -> None:
    async def body() -> None:
        async with running(settings, workspace) as h:
            mine = await h.submit([1, 1, 0], [7, 6, 0], token=SUBMITTER)
            theirs = await h.submit([1, 1, 0], [7, 6, 0], token=OTHER_SUBMITTER)
            assert mine["owner"] == "alice" and theirs["owner"] == "bob"
            assert (await h.client.get(f"/v1/mail/{mine['id']}", headers=auth(SUBMITTER))).status_code == 200
            assert (await h.client.get(f"/v1/mail/{theirs['id']}", headers=auth(SUBMITTER))).status_code == 404
            page = (await h.client.get("/v1/mail", headers=auth(SUBMITTER))).json()
            assert [m["id"] for m in page["items"]] == [mine["id"]]
            everything = (await h.client.get("/v1/mail", headers=auth(OPERATOR))).json()
            assert len(everything["items"]) == 2
            assert (await h.client.get("/v1/workspace", headers=auth(SUBMITTER))).status_code == 200
            for method, path in (("GET", "/v1/fleet"), ("POST", f"/v1/mail/{mine['id']}/cancel"),
                                 ("GET", "/v1/events")):
                res = await h.client.request(method, path, headers=auth(SUBMITTER))
                assert res.status_code == 403, path
                assert "operator" in res.json()["detail"]

    run(body())
