"""argparse types shared by the console tools (katana-curiosity, katana-run, katana-demo,
katana-robot): every option is checked while the command line is parsed, before any work, so
a bad value ends in one line naming the option, the subcommand's usage and exit code 2."""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path


def positive_int(text: str) -> int:
    return _int_at_least(text, 1)


def non_negative_int(text: str) -> int:
    return _int_at_least(text, 0)


def _int_at_least(text: str, low: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < low:
        raise argparse.ArgumentTypeError(f"must be >= {low}, got {value}")
    return value


def positive_seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a number of seconds > 0, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"a number of seconds > 0, got {text!r}")
    return value


def writable_folder(text: str) -> Path:
    """A folder that is created if missing and probed with a temporary file: a permission check
    alone does not see read-only or virtual file systems, nor root's rights."""
    path = Path(text)
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as err:
        raise argparse.ArgumentTypeError(
            f"cannot write in {path}: {err.strerror or err}") from None
    return path
