"""`python -m katana_paper.docs_report [--check] [collect NAME ...]`: write or check every
generated file against what the committed results make."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .benchmarks import render_benchmarks
from .readme import render_readme_block, splice_readme
from .reproducing import render_reproducing
from .sources import BENCHMARKS_MD, README_MD, REPRODUCING_MD, SOURCES, collect, load_results


def render_all(root: Path) -> dict[Path, str]:
    """Every generated file and the text it should hold."""
    results = load_results(root)
    readme = root / README_MD
    return {
        root / BENCHMARKS_MD: render_benchmarks(results),
        root / REPRODUCING_MD: render_reproducing(results),
        readme: splice_readme(readme.read_text(encoding="utf-8"), render_readme_block(results)),
    }


def find_root(start: Path) -> Path:
    """The repository around `start`, so that the command runs from any folder inside it."""
    for folder in (start, *start.parents):
        if (folder / "docs").is_dir() and (folder / "ros2_ws").is_dir():
            return folder
    raise FileNotFoundError(f"no repository (docs/ and ros2_ws/) at or above {start}")


def main(argv: list[str] | None = None) -> int:
    """Write (or with --check, compare) the generated files; 0 done, 1 stale, 2 an error."""
    parser = argparse.ArgumentParser(
        prog="python -m katana_paper.docs_report",
        description="Write docs/BENCHMARKS.md, docs/REPRODUCING.md and the results block of "
        "README.md from the committed result files.")
    parser.add_argument("--root", type=Path, default=None,
                        help="the repository (default: the one around the current folder)")
    parser.add_argument("--check", action="store_true",
                        help="write nothing; exit 1 if a generated file is not up to date")
    sub = parser.add_subparsers(dest="command")
    c = sub.add_parser("collect", help="copy results from where their commands write them to "
                       "docs/results/ (or docs/robot_truth.json), then write the pages")
    c.add_argument("names", nargs="+", choices=list(SOURCES), metavar="NAME",
                   help=", ".join(SOURCES))
    args = parser.parse_args(argv)
    try:
        root = (args.root or find_root(Path.cwd())).resolve()
        if args.command == "collect":
            for path in collect(root, args.names):
                print(f"docs_report: copied {path.relative_to(root)}")
        stale = []
        for path, text in render_all(root).items():
            if path.exists() and path.read_text(encoding="utf-8") == text:
                continue
            stale.append(path.relative_to(root))
            if not args.check:
                path.write_text(text, encoding="utf-8")
                print(f"docs_report: wrote {path.relative_to(root)}")
    except (OSError, ValueError) as exc:
        print(f"docs_report: {exc}", file=sys.stderr)
        return 2
    if args.check and stale:
        print(f"docs_report: not up to date: {', '.join(map(str, stale))}; run "
              "`python -m katana_paper.docs_report`", file=sys.stderr)
        return 1
    return 0
