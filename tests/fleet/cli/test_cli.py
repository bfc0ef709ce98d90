"""The ``drona`` command's own options and errors (each command has its tests beside its module's)."""

from __future__ import annotations

import importlib.metadata

import pytest

from fleet.cli import build_parser, main
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


def test_a_shared_option_before_the_bench_is_kept() -> None:
    args = build_parser("bench").parse_args(["bench", "--quick", "--seed", "7", "planner", "--json"])
    assert (args.quick, args.seed, args.json, args.what) == (True, 7, True, "planner")
    assert build_parser("bench").parse_args(["bench", "planner"]).quick is False


def test_another_benchs_option_still_parses_and_is_named_as_ignored(capsys: pytest.CaptureFixture[str]) -> None:
    """Command lines from when every bench took every option keep working; the option is said to do nothing."""
    assert main(["bench", "planner", "--grids", "16", "--drones", "4", "--tasks", "2", "--no-smt", "--json",
                 "--warmup", "1", "--insecure"]) == 0
    assert "drona bench planner: ignoring --insecure, --warmup (not an option of this bench)" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["bench", "coordination", "--help"])
    assert "--warmup" not in capsys.readouterr().out


def test_bench_help_lists_the_benches_not_their_options(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["bench", "--help"])
    out = capsys.readouterr().out
    assert all(name in out for name in ("planner", "mavlink", "coordination", "api"))
    assert "--agents" not in out and "--rate" not in out
