"""katana-demo's terminal: a progress bar and one line per experiment, the nodes' log in a file.

The nodes log through rcutils, which writes to the process's standard error (file descriptor
2) from C; so the nodes' lines are moved by pointing descriptor 2 at `<run>/nodes.log`, and the
bar and the experiment lines go to a duplicate of the terminal's descriptor taken before. The
bar (tqdm) shows only on a terminal; the lines are written everywhere (a log file, Ray's
per-run stdout.log).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import TextIO

from tqdm import tqdm

NODES_LOG_NAME = "nodes.log"


def experiment_line(index: int, mode: str, height: int, action: int, label: int,
                    block: str) -> str:
    """One experiment as the terminal shows it (0-based index, 1-based action)."""
    outcome = "stable" if label > 0 else "fell"
    return f"#{index:<4d} {mode:<6s} h={height} a={action} {outcome:<6s} block {block}"


class RunTerminal:
    """The terminal of one run: node log lines to `<run_dir>/nodes.log` (unless `verbose`), and,
    after `start`, a bar over the run's experiments with one line per experiment above it."""

    def __init__(self, run_dir: Path, verbose: bool = False) -> None:
        self.log_path: Path | None = None
        self._saved_stderr: int | None = None
        self.bar: tqdm | None = None
        sys.stderr.flush()
        self.terminal: TextIO = os.fdopen(os.dup(2), "w", buffering=1, encoding="utf-8")
        if not verbose:
            self.log_path = Path(run_dir) / NODES_LOG_NAME
            self._saved_stderr = os.dup(2)
            log_fd = os.open(self.log_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
            os.dup2(log_fd, 2)
            os.close(log_fd)

    def start(self, total: int, done: int) -> None:
        """The bar, at `done` of `total` (a resumed run starts where it stopped)."""
        self.bar = tqdm(total=total, initial=min(done, total), unit="exp", file=self.terminal,
                        dynamic_ncols=True, disable=None, leave=True)

    def experiment(self, line: str) -> None:
        """One line above the bar, and the bar one further."""
        self.say(line)
        if self.bar is not None:
            self.bar.update(1)

    def say(self, text: str) -> None:
        if self.terminal.closed:
            return
        if self.bar is not None:
            self.bar.write(text, file=self.terminal)
        else:
            print(text, file=self.terminal, flush=True)

    def close(self) -> None:
        """The bar ends and standard error is the terminal again (idempotent)."""
        if self.bar is not None:
            self.bar.close()
            self.bar = None
        sys.stderr.flush()
        if self._saved_stderr is not None:
            os.dup2(self._saved_stderr, 2)
            os.close(self._saved_stderr)
            self._saved_stderr = None
        if not self.terminal.closed:
            self.terminal.close()
