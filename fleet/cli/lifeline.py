"""A child that dies with its launcher: ``python -m fleet.cli.lifeline FD COMMAND ARGS...``.

It runs ``drona COMMAND ARGS...`` and watches the read end ``FD`` of a pipe whose write end
only the launcher holds. When every write end is closed — the launcher exited, however: a
crash or ``kill -9`` included — the read returns EOF, and the child SIGKILLs its process
group, so that whatever it started in its group goes too. ``drona demo`` starts its
children this way (each in its own session, so each leads its own group).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import sys
import threading
from collections.abc import Sequence

from fleet.cli import main as drona

#: A folder the launcher would have removed on its way out (``drona demo``'s state): removed at EOF.
LEFTOVERS = "DRONA_LIFELINE_LEFTOVERS"


def watch(fd: int) -> None:
    """From now on, die (with the process group this process leads) when ``fd`` reaches EOF."""
    os.set_inheritable(fd, False)  # what this process starts need not hold the launcher's pipe
    threading.Thread(target=_die_at_eof, args=(fd, os.environ.get(LEFTOVERS)), name="lifeline", daemon=True).start()


def _die_at_eof(fd: int, leftovers: str | None) -> None:
    with contextlib.suppress(OSError):
        while os.read(fd, 64):  # the launcher writes nothing; EOF is its end
            pass
    if leftovers:  # every child may try: the first removes it
        shutil.rmtree(leftovers, ignore_errors=True)
    # SIGKILL, not a graceful stop: the launcher that stops the pieces in order (agents land
    # before their vehicles stop) is gone, the pieces alone cannot, and the service's store
    # is built to lose nothing acknowledged on kill -9. Its ports must be free at once.
    if os.getpgrp() == os.getpid():  # leads its own group: take the group (grandchildren) along
        os.killpg(os.getpid(), signal.SIGKILL)
    os.kill(os.getpid(), signal.SIGKILL)


def main(argv: Sequence[str]) -> int:
    if len(argv) < 2 or not argv[0].isdigit():
        print("usage: python -m fleet.cli.lifeline FD COMMAND [ARGS...]", file=sys.stderr)
        return 2
    watch(int(argv[0]))
    return drona(argv[1:])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
