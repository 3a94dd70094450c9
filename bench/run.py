"""`make bench`: run every bench/bench_*.py and write bench/results/<name>.json.

Each module offers run() -> dict. Figures are wall-clock on this machine; each bench repeats
its measurement and reports medians, since a shared 2-core VM is noisy.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import platform
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("names", nargs="*", help="benches to run (default: all), e.g. core sim")
    parser.add_argument("--out", type=Path, default=HERE / "results")
    args = parser.parse_args()
    available = {p.stem.removeprefix("bench_"): p for p in sorted(HERE.glob("bench_*.py"))}
    unknown = [n for n in args.names if n not in available]
    if unknown:
        parser.error(f"unknown bench {', '.join(unknown)}: choose from {', '.join(available)}")
    args.out.mkdir(parents=True, exist_ok=True)
    failed = []
    for name in args.names or list(available):
        spec = importlib.util.spec_from_file_location(f"bench_{name}", available[name])
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        print(f"bench {name}: running", flush=True)
        start = time.perf_counter()
        try:
            result = module.run()
        except Exception as exc:  # report and go on: one broken bench must not hide the others
            print(f"bench {name}: FAILED: {exc!r}", file=sys.stderr)
            failed.append(name)
            continue
        result = {
            "bench": name,
            "machine": machine(),
            "bench_wall_s": round(time.perf_counter() - start, 2),
            **result,
        }
        path = args.out / f"{name}.json"
        path.write_text(json.dumps(result, indent=2) + "\n")
        print(json.dumps(result, indent=2))
        print(f"bench {name}: wrote {path}")
    return 1 if failed else 0


def machine() -> dict:
    """Where the figures were measured (a bench run as a script records it too)."""
    return {
        "python": platform.python_version(),
        "cpus": _cpus(),
        "cpu_model": _cpu_model(),
        "platform": platform.platform(),
    }


def _cpus() -> int:
    return os.cpu_count() or 0


def _cpu_model() -> str:
    """The processor's name (figures from different CPUs differ by up to 2.6x in physics)."""
    try:
        for line in Path("/proc/cpuinfo").read_text(encoding="utf-8").splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


if __name__ == "__main__":
    sys.exit(main())
