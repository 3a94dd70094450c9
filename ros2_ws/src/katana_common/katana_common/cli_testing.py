"""For the console tools' tests (hypothesis, a test dependency): `refused` runs a tool's main()
in-process and checks that it refused the command line the one way every tool refuses
(katana_common.cli_args), `tree` lists what a refusal must leave unchanged, and the strategies
draw bad values of each kind of option."""

from __future__ import annotations

import argparse
import os
from collections.abc import Callable

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

#: words that are no number (nor nan/inf, which float() takes)
words = st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,10}", fullmatch=True).filter(
    lambda t: t.lower() not in ("nan", "inf", "infinity"))
#: plain file and folder names
names = st.from_regex(r"[a-z][a-z0-9_]{0,10}", fullmatch=True)


def cli_settings(max_examples: int) -> settings:
    """hypothesis settings of a command-line property test: tmp_path (a function-scoped
    fixture) is the working folder every example leaves as it found it."""
    return settings(suppress_health_check=[HealthCheck.function_scoped_fixture], deadline=None,
                    max_examples=max_examples)


def refused(main: Callable[[list[str]], object], argv: list[str], capsys) -> str:
    """Run `main(argv)` and check the refusal: exit code 2, the usage first, one error line
    last, no traceback. Returns that line for the caller's checks of the option it names
    (pytest's `capsys` captures the output)."""
    capsys.readouterr()
    try:
        main(argv)
    except SystemExit as stop:
        code = stop.code
    else:
        raise AssertionError(f"{argv} was accepted")
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2, (argv, code, err)
    assert lines and lines[0].startswith("usage: "), (argv, err)
    errors = [line for line in lines if ": error: " in line]
    assert errors == [lines[-1]], (argv, err)
    assert "Traceback" not in err, (argv, err)
    return lines[-1]


def tree(folder) -> list[str]:
    """Every file and folder under `folder`, relative and sorted."""
    return sorted(os.path.relpath(os.path.join(root, name), folder)
                  for root, dirs, files in os.walk(folder) for name in dirs + files)


def ints_outside(low: int, high: int | None = None) -> st.SearchStrategy[str]:
    """Text that is no whole number in [low, high]."""
    outside = st.integers(max_value=low - 1)
    if high is not None:
        outside |= st.integers(min_value=high + 1)
    fractions = st.floats(allow_nan=False, allow_infinity=False).filter(
        lambda v: not v.is_integer())
    return outside.map(str) | words | fractions.map(repr)


def floats_outside(low: float, high: float | None = None,
                   low_open: bool = False) -> st.SearchStrategy[str]:
    """Text that is no finite number from low (excluded if low_open) to high."""
    below = st.floats(max_value=low, allow_nan=False).filter(
        lambda v: v <= low if low_open else v < low)
    outside = below | st.sampled_from([float("nan"), float("inf"), float("-inf")])
    if high is not None:
        outside |= st.floats(min_value=high, exclude_min=True)
    return outside.map(repr) | words


def not_one_of(choices) -> st.SearchStrategy[str]:
    return words.filter(lambda t: t not in choices)


#: folders no one can write in, relative to a working folder holding a file `file.txt`
folders = st.one_of(st.just(""), names.map(lambda n: f"file.txt/{n}"),
                    names.map(lambda n: f"/proc/{n}/x"), st.just("x" * 300))


def unwritable_files(suffix: str) -> st.SearchStrategy[str]:
    """Files ending in `suffix` that cannot be written (with a folder `folder<suffix>` in the
    working folder), and names with another suffix."""
    return st.one_of(names.map(lambda n: f"{n}.bag"), names.map(lambda n: f"missing/{n}{suffix}"),
                     names.map(lambda n: f"/proc/{n}{suffix}"), st.just(f"file.txt/run{suffix}"),
                     st.just(f"folder{suffix}"), st.just(""))


#: MCAP files that cannot be written
mcaps = unwritable_files(".mcap")
#: files to read that are not there
missing_files = names.map(lambda n: f"missing-{n}.yaml") | st.sampled_from([".", ""])


#: what bad_working_folder makes: a refused command line leaves the folder so
BAD_WORKING_TREE = ["file.txt", "folder.mcap", "folder.png"]


def bad_working_folder(folder) -> None:
    """The file and the folders the strategies above point at (BAD_WORKING_TREE)."""
    (folder / "file.txt").write_text("x")
    (folder / "folder.mcap").mkdir()
    (folder / "folder.png").mkdir()


def unknown_flags(parser: argparse.ArgumentParser) -> st.SearchStrategy[str]:
    """Options the parser (or its subcommands) does not have, nor abbreviates."""
    known = [o for action in parser._actions for o in action.option_strings]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            known += [o for sub in action.choices.values() for a in sub._actions
                      for o in a.option_strings]
    return st.from_regex(r"--[a-z][a-z-]{0,12}", fullmatch=True).filter(
        lambda f: not any(o.startswith(f) for o in known))
