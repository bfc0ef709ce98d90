"""Issue 26, in small: the lifeline that ties ``drona demo``'s children to it (the whole demo,
killed with -9, is in tests/integration/test_demo.py)."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]

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
