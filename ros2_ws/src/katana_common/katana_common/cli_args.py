"""The command-line validator every console tool shares (katana-run, katana-demo, katana-robot,
katana-curiosity, katana-emulator): argparse types that check a value while the command line is
parsed, and `parse_command_line`, which parses (an unknown option is refused), then runs the
checks argparse cannot express (across options, parameter files) and only then returns.

A bad command line ends before any work: the (sub)command's usage, one line naming the option
(`prog: error: argument --out: ...`), exit code 2 (EXIT_USAGE), no traceback, and nothing
created. The types only look: a folder to be written is probed (a nameless temporary file in
it, or in its nearest existing parent), never made; the command makes it once every check
passed. A check raises `CommandLineError(option, why)`.
"""

from __future__ import annotations

import argparse
import math
import os
import socket
import tempfile
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

#: the exit code of a refused command line (argparse's, and node_runner's invalid configuration)
EXIT_USAGE = 2


class CommandLineError(Exception):
    """A bad command line found by a check after parsing; `option` names what is wrong."""

    def __init__(self, option: str, why: str) -> None:
        super().__init__(f"argument {option}: {why}")
        self.option = option
        self.why = why


Check = Callable[[argparse.Namespace], None]


def parse_command_line(parser: argparse.ArgumentParser, argv: Sequence[str] | None,
                       checks: Iterable[Check] = ()) -> argparse.Namespace:
    """`argv` parsed (every option's type checks its value; an unknown option is refused),
    then every check run in order. The first refusal exits 2 with the usage of the subcommand
    the command line chose and one line naming the option; nothing is done before."""
    args = parser.parse_args(argv)
    chosen = chosen_parser(parser, args)
    for check in checks:
        try:
            check(args)
        except CommandLineError as err:
            chosen.error(_one_line(str(err)))
    return args


def chosen_parser(parser: argparse.ArgumentParser,
                  args: argparse.Namespace) -> argparse.ArgumentParser:
    """The parser of the subcommand `args` chose (nested), or `parser` without subcommands."""
    for action in parser._actions:  # argparse offers no public accessor for its subparsers
        if isinstance(action, argparse._SubParsersAction):
            name = getattr(args, action.dest, None)
            if name in action.choices:
                return chosen_parser(action.choices[name], args)
    return parser


def _one_line(text: str) -> str:
    return " ".join(text.split())


# -- numbers --------------------------------------------------------------------------------
def int_in(low: int | None = None, high: int | None = None) -> Callable[[str], int]:
    """A whole number in [low, high] (either bound may be open-ended)."""

    def whole_number(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
        if (low is not None and value < low) or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"must be {_range_text(low, high)}, got {value}")
        return value

    return whole_number


def float_in(low: float | None = None, high: float | None = None, *, low_open: bool = False,
             high_open: bool = False, what: str = "a number") -> Callable[[str], float]:
    """A finite number in the interval from low to high (open at a bound when asked)."""

    def number(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        inside = math.isfinite(value)
        if inside and low is not None:
            inside = value > low if low_open else value >= low
        if inside and high is not None:
            inside = value < high if high_open else value <= high
        if not inside:
            bounds = _range_text(low, high, low_open, high_open)
            raise argparse.ArgumentTypeError(f"must be {bounds}, got {text!r}")
        return value

    return number


def _range_text(low, high, low_open: bool = False, high_open: bool = False) -> str:
    if high is None:
        return f"{'>' if low_open else '>='} {low:g}" if low is not None else "finite"
    if low is None:
        return f"{'<' if high_open else '<='} {high:g}"
    return f"in {'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"


positive_int = int_in(1)
non_negative_int = int_in(0)
#: a TCP port to listen on or connect to (0: any free port)
tcp_port = int_in(0, 65535)
positive_seconds = float_in(0.0, low_open=True, what="a number of seconds")
non_negative_seconds = float_in(0.0, what="a number of seconds")
positive_number = float_in(0.0, low_open=True)
#: a probability or a share, [0, 1]
fraction = float_in(0.0, 1.0, what="a fraction")


def comma_list(choices: Iterable[str], what: str = "name") -> Callable[[str], str]:
    """Comma-separated names, each one of `choices`; the text is returned as given."""
    valid = tuple(choices)

    def names(text: str) -> str:
        given = [n.strip() for n in text.split(",") if n.strip()]
        unknown = [n for n in given if n not in valid]
        if not given or unknown:
            raise argparse.ArgumentTypeError(
                f"unknown {what}(s) {', '.join(unknown) or '(none given)'}: choose from "
                f"{', '.join(sorted(valid))}")
        return text

    return names


def from_spec(spec: Any, *, at_least: float | None = None) -> Callable[[str], Any]:
    """An option that sets a node parameter: its text read as the type of `spec.default` (a
    katana_common Param) and checked by the spec's own rule, as the node would check it (and
    at least `at_least`, where the option is narrower than the parameter)."""
    kind = type(spec.default)

    def value_of(text: str) -> Any:
        try:
            value = kind(text) if kind in (int, float) else text
        except ValueError:
            name = "whole number" if kind is int else "number"
            raise argparse.ArgumentTypeError(f"expected a {name}, got {text!r}") from None
        if at_least is not None and kind in (int, float) and not value >= at_least:
            raise argparse.ArgumentTypeError(f"must be >= {at_least:g}, got {value!r}")
        reason = spec.problem(value)
        if reason:
            if "is not one of" not in reason:
                reason += f"; valid: {spec.valid_text()}"
            raise argparse.ArgumentTypeError(reason)
        return value

    return value_of


def listen_host(text: str) -> str:
    """A host name or address this machine can listen on (resolved now, as the listener will)."""
    if not text or "\0" in text:
        raise argparse.ArgumentTypeError(f"expected a host name or address, got {text!r}")
    try:
        socket.getaddrinfo(text, None, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (OSError, UnicodeError) as err:
        raise argparse.ArgumentTypeError(
            f"cannot resolve {text!r}: {getattr(err, 'strerror', None) or err}") from None
    return text


# -- files and folders ----------------------------------------------------------------------
def writable_folder(text: str) -> Path:
    """A folder the command can write in: an existing one, or one that can be made (its nearest
    existing parent is a folder that takes a file). Nothing is created here: the probe is a
    nameless temporary file, and a read-only or virtual file system fails it, whatever the
    permission bits say (root)."""
    path = _path(text, "a folder")
    existing = path
    try:
        existing = next(p for p in (path, *path.parents) if p.exists())
        if not existing.is_dir():
            where = "is a file" if existing == path else f"is inside a file ({existing})"
            raise argparse.ArgumentTypeError(f"{path} {where}, not a folder")
        _check_names(path, existing)
        _probe(existing)
    except OSError as err:
        where = "" if existing == path else f" ({existing} takes no new file)"
        raise argparse.ArgumentTypeError(
            f"cannot write in {path}{where}: {err.strerror or err}") from None
    return path


def new_file(suffix: str) -> Callable[[str], Path]:
    """A file to write, ending in `suffix`, in an existing folder that takes a file; an existing
    file must be writable (it is replaced). Nothing is created here."""

    def file_to_write(text: str) -> Path:
        path = _path(text, f"a file name ending in {suffix}")
        if path.suffix != suffix or path.name == suffix:
            raise argparse.ArgumentTypeError(f"a file name ending in {suffix}, got {text!r}")
        folder = path.parent
        try:
            if path.is_dir():
                raise argparse.ArgumentTypeError(f"{path} is a folder, not a file")
            if not folder.is_dir():
                raise argparse.ArgumentTypeError(f"no folder {folder} for {path.name}")
            _check_names(path, folder)
            _probe(folder)
            if path.exists():
                with open(path, "r+b"):  # opens for writing without changing it
                    pass
        except OSError as err:
            raise argparse.ArgumentTypeError(
                f"cannot write {path}: {err.strerror or err}") from None
        return path

    return file_to_write


def readable_file(text: str) -> Path:
    """An existing regular file this process can read."""
    path = _path(text, "a file")
    try:
        if not path.is_file():
            why = "is a folder" if path.is_dir() else "does not exist"
            raise argparse.ArgumentTypeError(f"{path} {why}; expected a readable file")
        with open(path, "rb") as fh:
            fh.read(1)
    except OSError as err:
        raise argparse.ArgumentTypeError(
            f"cannot read {path}: {err.strerror or err}") from None
    return path


def _path(text: str, what: str) -> Path:
    """`text` as a path, `~` expanded (an option given as --out=~/x reaches us unexpanded)."""
    if not text or "\0" in text:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    try:
        return Path(text).expanduser()
    except RuntimeError:  # ~user of no known user: the name as it is
        return Path(text)


def _check_names(path: Path, existing: Path) -> None:
    """Every part of `path` below `existing` is a name the file system can take."""
    limit = os.pathconf(existing, "PC_NAME_MAX")
    for part in path.relative_to(existing).parts:
        if len(os.fsencode(part)) > limit:
            raise argparse.ArgumentTypeError(f"name too long ({limit} bytes at most): {part!r}")


def _probe(folder: Path) -> None:
    """Raises OSError unless a file can be written in `folder` (the probe leaves nothing)."""
    with tempfile.TemporaryFile(dir=folder):
        pass
