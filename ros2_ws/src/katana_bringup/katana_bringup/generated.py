"""The command line of a generated file's module: `--write` rewrites the files whose text differs
from what their generator gives; without it, each such file is named and the exit status is 1
(the tests and `make` check the packaged files this way)."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Mapping
from pathlib import Path


def stale(files: Mapping[Path, Callable[[], str]]) -> list[Path]:
    """The files whose text differs from what their generator gives (missing ones too)."""
    return [path for path, render in files.items()
            if not path.is_file() or path.read_text() != render()]


def write_or_check(prog: str, description: str, files: Mapping[Path, Callable[[], str]],
                   source: str, argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=prog, description=description)
    parser.add_argument("--write", action="store_true", help="rewrite the stale files")
    args = parser.parse_args(argv)
    paths = stale(files)
    for path in paths:
        if args.write:
            path.write_text(files[path]())
            print(f"wrote {path}")
        else:
            print(f"{path} differs from {source}: run with --write")
    return 1 if paths and not args.write else 0
