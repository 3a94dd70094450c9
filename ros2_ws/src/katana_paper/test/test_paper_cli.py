"""Every bad command line of katana-robot and katana-curiosity is refused before any work: exit
2, the subcommand's usage, one line naming the option, no traceback, and the working folder
unchanged (no output folder left behind). Property-based over each option's bad values,
in-process (main(argv) with a temporary folder as the working folder)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st
from katana_common.cli_testing import (
    BAD_WORKING_TREE,
    bad_working_folder,
    cli_settings,
    floats_outside,
    folders,
    ints_outside,
    missing_files,
    names,
    not_one_of,
    refused,
    tree,
    unknown_flags,
    words,
)
from katana_curiosity.core.strategies import STRATEGIES
from katana_paper import curiosity_cli, robot_cli

CHECKS = cli_settings(30)

_strategy_lists = not_one_of(STRATEGIES) | st.sampled_from([",", "q1,bogus", ""])
_bands = st.sampled_from(["0.9,0.1", "0.5", "a,b", "-0.1,0.5", "0.2,1.5", "nan,0.5", ""])
_grid = (words | st.sampled_from(["alpha=", "bogus=1", "alpha=x", "alpha=-1", "theta=2",
                                  "gamma=1", "n_blocks=1", "n_features=0", "alpha=1,1"]))

#: subcommand -> (the arguments it needs, {option: bad values})
ROBOT = {
    "truth": ([], {
        "--trials": ints_outside(1), "--out": folders, "--seed": ints_outside(0),
        "--max-height": ints_outside(1, 3), "--actions": ints_outside(6, 6)}),
    "paper": (["--truth=file.txt"], {
        "--seeds": ints_outside(1), "--seed0": ints_outside(0), "--experiments": ints_outside(1),
        "--strategies": _strategy_lists, "--methods": _strategy_lists,
        "--jobs": ints_outside(1), "--out": folders, "--truth": missing_files,
        "--domain-base": ints_outside(0, 232), "--run-timeout": floats_outside(0.0, low_open=True),
        "--contact-first": ints_outside(0)}),
    "skill": (["--model=file.txt"], {
        "--goal-height": ints_outside(1, 4), "--trials": ints_outside(1),
        "--model": missing_files | st.just("folder.mcap"), "--seed": ints_outside(0),
        "--max-placements": ints_outside(1), "--out": folders}),
    "claims": (["folder.mcap"], {
        "--resamples": ints_outside(1), "--bootstrap-seed": ints_outside(0),
        "--uncertain": _bands}),
}
_RUNS = {
    "--experiments": ints_outside(1), "--steps": ints_outside(1), "--seeds": ints_outside(1),
    "--first-seed": ints_outside(0), "--strategies": _strategy_lists,
    "--methods": _strategy_lists, "--alpha": floats_outside(0.0, low_open=True),
    "--theta": floats_outside(0.0, 1.0), "--gamma": floats_outside(0.0, 1.0), "--out": folders,
}
CURIOSITY = {
    "paper": (["--out=out"], {**_RUNS, "--jobs": ints_outside(1)}),
    "explore": (["--out=out"], {**_RUNS, "--jobs": ints_outside(1)}),
    "sweep": (["--out=out", "--grid=alpha=1"], {**_RUNS, "--grid": _grid,
                                                "--num-cpus": ints_outside(1)}),
    "claims": (["folder.mcap"], {"--resamples": ints_outside(1),
                                 "--bootstrap-seed": ints_outside(0)}),
}


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    """A working folder with the files the bad values point at; each command's work replaced
    by a failure, so that a command line let through cannot start it."""
    monkeypatch.chdir(tmp_path)
    bad_working_folder(tmp_path)

    def work(*_a, **_k):
        raise AssertionError("the work started")

    for name in robot_cli.COMMANDS:
        monkeypatch.setitem(robot_cli.COMMANDS, name, work)
    for name in ("run_many", "run_sweep", "cmd_curiosity_claims", "_explore_with_progress"):
        monkeypatch.setattr(curiosity_cli, name, work)
    return tmp_path


def _check(main, prog, table, data, capsys, folder):
    command = data.draw(st.sampled_from(sorted(table)))
    needed, options = table[command]
    option = data.draw(st.sampled_from(sorted(options)))
    value = data.draw(options[option])
    rest = [a for a in needed if not a.startswith(f"{option}=")]
    if option == "--grid":  # one --grid only: a second one for the same axis is another error
        rest = [a for a in rest if not a.startswith("--grid")]
    before = tree(folder)
    line = refused(main, [command, *rest, f"{option}={value}"], capsys)
    assert line.startswith(f"{prog} {command}: error: argument ") and option in line, line
    assert tree(folder) == before


@CHECKS
@given(data=st.data())
def test_katana_robot_refuses_a_bad_value_of_any_option_naming_it(workdir, capsys, data):
    _check(robot_cli.main, "katana-robot", ROBOT, data, capsys, workdir)


@CHECKS
@given(data=st.data())
def test_katana_curiosity_refuses_a_bad_value_of_any_option_naming_it(workdir, capsys, data):
    _check(curiosity_cli.main, "katana-curiosity", CURIOSITY, data, capsys, workdir)


@CHECKS
@given(data=st.data())
@pytest.mark.parametrize("tool", [robot_cli, curiosity_cli],
                         ids=["katana-robot", "katana-curiosity"])
def test_an_unknown_option_or_subcommand_is_refused(workdir, capsys, data, tool):
    table = ROBOT if tool is robot_cli else CURIOSITY
    command = data.draw(st.sampled_from(sorted(table)))
    flag = data.draw(unknown_flags(tool.build_parser()))
    line = refused(tool.main, [command, *table[command][0], flag], capsys)
    assert "unrecognized arguments" in line and flag in line
    other = data.draw(names.filter(lambda n: n not in table))
    assert "invalid choice" in refused(tool.main, [other], capsys)
    assert tree(workdir) == BAD_WORKING_TREE


@pytest.mark.parametrize("argv, named", [
    (["skill", "--model", "MISSING"], "argument --model: no learner.npz in 'MISSING'"),
    (["paper", "--methods", "bogus", "--truth", "file.txt"],
     "argument --strategies/--methods: unknown strategy(s) bogus"),
    (["paper"], "argument --truth: no measured truth at runs/robot-truth/truth.json"),
    (["paper", "--truth", "file.txt", "--domain-base", "231", "--jobs", "2"],
     "argument --domain-base: 231 leaves no room for --jobs 2"),
])
def test_katana_robot_leaves_no_output_folder_behind(workdir, capsys, argv, named):
    """Before, the default --out (runs/robot-skill, runs/robot-paper) was made while parsing."""
    assert named in refused(robot_cli.main, argv, capsys)
    assert tree(workdir) == BAD_WORKING_TREE


@pytest.mark.parametrize("argv, named", [
    (["paper", "--out", "o", "--alpha", "inf"], "argument --alpha: must be > 0, got 'inf'"),
    (["sweep", "--out", "o", "--grid", "n_blocks=1"], "argument --grid: n_blocks must be in"),
    (["sweep", "--out", "o", "--grid", "alpha=1", "--grid", "alpha=2"],
     "argument --grid: each parameter may be given once"),
])
def test_katana_curiosity_checks_what_its_runs_would_refuse(workdir, capsys, argv, named):
    assert named in refused(curiosity_cli.main, argv, capsys)
    assert tree(workdir) == BAD_WORKING_TREE
