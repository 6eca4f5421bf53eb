"""The ``hmpc`` entry point's own behaviour, and the benchmarks' verdicts."""

from __future__ import annotations

import copy

import pytest

from _data import REPORT_PARAMS
from hmpc.models.params import load_params
from hmpc.tools import bench_identify, cli


def test_every_declared_subcommand_is_in_the_parser(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for name in cli.SUBCOMMANDS:
        assert f"    {name} " in out, name


def test_a_subcommand_without_its_module_is_an_internal_error(monkeypatch, capsys):
    """A missing module is a broken install, never a subcommand dropped from --help: the
    overview still lists it and running it is an internal error (exit 1)."""
    monkeypatch.setitem(cli.SUBCOMMANDS, "nope", ("hmpc.tools.cmd_nope", "not built"))
    with pytest.raises(cli.MissingSubcommandError, match="'nope'.*hmpc.tools.cmd_nope"):
        cli.build_parser()
    assert cli.main(["nope", "--help"]) == 1
    err = capsys.readouterr().err
    assert "internal error" in err and "hmpc.tools.cmd_nope" in err


def test_a_broken_subcommand_module_is_not_hidden(monkeypatch, tmp_path):
    """An import error INSIDE a subcommand's module propagates as itself (a missing dependency,
    named), not as a missing subcommand."""
    (tmp_path / "hmpc_probe_broken_cmd.py").write_text("import hmpc_no_such_dependency_probe\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(cli.SUBCOMMANDS, "broken", ("hmpc_probe_broken_cmd", "x"))
    with pytest.raises(ModuleNotFoundError) as exc:
        cli.build_parser()
    assert exc.value.name == "hmpc_no_such_dependency_probe"
    assert not isinstance(exc.value, cli.MissingSubcommandError)


def test_bench_identify_fails_on_a_wrong_answer():
    truth = load_params(REPORT_PARAMS)
    assert bench_identify.accuracy_failures(truth, truth) == []
    wrong = copy.deepcopy(truth)
    wrong.steering.scale *= 1.03
    wrong.zones[1].brake_scale_mps2 *= 0.9
    bad = bench_identify.accuracy_failures(wrong, truth)
    assert len(bad) == 2 and "steering scale" in bad[0] and "zone low brake scale" in bad[1]
