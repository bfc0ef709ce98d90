"""Issue 26, in small: the lifeline that ties ``drona demo``'s children to it, and the demo's token
beside ``DRONA_API_TOKENS`` (the whole demo, killed with -9, is in tests/integration/test_demo.py)."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from api.auth import Principal, Role
from fleet.cli import build_parser
from fleet.cli.serve import _settings

REPO = Path(__file__).resolve().parents[3]

#: A child on a lifeline that starts a grandchild in its process group and prints the grandchild's pid.
CHILD = ("import subprocess, sys, time\n"
         "from fleet.cli.lifeline import watch\n"
         "watch(int(sys.argv[1]))\n"
         "print(subprocess.Popen(['sleep', '60']).pid, flush=True)\n"
         "time.sleep(60)\n")


def alive(pid: int) -> bool:
    """Running (a zombie waiting for its reaper counts as gone)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def gone_within(pids: list[int], timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while any(alive(p) for p in pids):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def start_child(read_end: int) -> tuple[subprocess.Popen[str], int]:
    """The child (own session, as the demo starts it) and its grandchild's pid."""
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(read_end)], cwd=REPO, pass_fds=(read_end,),
                             start_new_session=True, stdout=subprocess.PIPE, text=True)
    assert child.stdout is not None
    return child, int(child.stdout.readline())


def reap(child: subprocess.Popen[Any]) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.killpg(child.pid, signal.SIGKILL)  # its group: the grandchild too, if a test failed
    child.communicate(timeout=10)


def test_a_child_on_a_lifeline_dies_with_its_grandchildren_when_the_launcher_goes() -> None:
    read_end, write_end = os.pipe()
    try:
        child, grandchild = start_child(read_end)
    finally:
        os.close(read_end)
    try:
        time.sleep(0.3)
        assert child.poll() is None and alive(grandchild)  # the launcher is here: they live
        os.close(write_end)  # what the kernel does when the launcher dies, kill -9 included
        assert gone_within([child.pid, grandchild], timeout=5.0)
        assert child.wait(5) == -signal.SIGKILL
    finally:
        reap(child)


def test_a_child_whose_launcher_died_before_it_started_watching_dies_too() -> None:
    read_end, write_end = os.pipe()
    os.close(write_end)  # gone before the child even reads its lifeline: no race
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(read_end)], cwd=REPO, pass_fds=(read_end,),
                             start_new_session=True, stdout=subprocess.DEVNULL)
    os.close(read_end)
    try:
        assert child.wait(30) == -signal.SIGKILL
    finally:
        reap(child)


def serve_settings(monkeypatch: pytest.MonkeyPatch, tokens: str, *options: str) -> tuple[Any, str | None]:
    """``drona serve --demo OPTIONS`` as the demo starts it, with ``DRONA_API_TOKENS=tokens``."""
    monkeypatch.setenv("DRONA_API_TOKENS", tokens)
    monkeypatch.delenv("DRONA_API_TOKEN_FILE", raising=False)
    return _settings(build_parser("serve").parse_args(["serve", "--workspace", "ws.yaml", "--demo", *options]))


def test_the_demo_token_also_listed_as_an_operator_s_is_that_operator(monkeypatch: pytest.MonkeyPatch) -> None:
    settings, made = serve_settings(monkeypatch, "operator:T0123:alice submitter:S0123", "--token", "T0123")
    table = settings.token_table()
    assert made == "T0123"
    assert table.lookup("T0123") == Principal("alice", Role.OPERATOR)  # the listing stands, its name too
    assert table.lookup("S0123") is not None and len(list(table.entries())) == 2


def test_the_demo_token_joins_the_listed_ones(monkeypatch: pytest.MonkeyPatch) -> None:
    settings, _ = serve_settings(monkeypatch, "submitter:S0123", "--token", "T0123")
    table = settings.token_table()
    assert table.lookup("T0123") == Principal("demo", Role.OPERATOR)
    assert table.lookup("S0123") is not None


def test_the_demo_token_listed_as_a_submitter_s_is_a_conflict_named(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(ValueError, match="--token is bob's submitter token in DRONA_API_TOKENS") as error:
        serve_settings(monkeypatch, "submitter:T0123:bob", "--token", "T0123")
    assert "T0123" not in str(error.value)  # a secret never shows


def test_the_demo_token_listed_in_the_token_file_is_that_operator(monkeypatch: pytest.MonkeyPatch,
                                                                  tmp_path: Path) -> None:
    (tmp_path / "tokens").write_text("operator:T0123:carol\n")
    monkeypatch.setenv("DRONA_API_TOKEN_FILE", str(tmp_path / "tokens"))
    monkeypatch.delenv("DRONA_API_TOKENS", raising=False)
    settings, _ = _settings(build_parser("serve").parse_args(
        ["serve", "--workspace", "ws.yaml", "--demo", "--token", "T0123"]))
    assert settings.token_table().lookup("T0123") == Principal("carol", Role.OPERATOR)
