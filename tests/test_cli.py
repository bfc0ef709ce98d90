"""The ``drona`` command's own options and errors (each command has its tests beside its module's)."""

from __future__ import annotations

import importlib.metadata

import pytest

from fleet.cli import main
from fleet.transport.wire import VERSION


def test_version_names_the_package_and_the_wire_protocol(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert out == f"drona {importlib.metadata.version('drona-gcs')} (wire protocol {VERSION})\n"


def test_an_option_before_any_command_is_named(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["--bogus"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "unknown option --bogus" in err and "plan, bench, verify" in err


def test_each_bench_takes_only_its_own_options(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["bench", "coordination", "--rate", "5"])  # an option of bench api
    assert exit_.value.code == 2
    assert "unrecognized arguments: --rate 5" in capsys.readouterr().err


def test_bench_help_lists_the_benches_not_their_options(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["bench", "--help"])
    out = capsys.readouterr().out
    assert all(name in out for name in ("planner", "mavlink", "coordination", "api"))
    assert "--agents" not in out and "--rate" not in out
