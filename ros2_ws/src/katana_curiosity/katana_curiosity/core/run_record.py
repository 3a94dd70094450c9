"""What a robot run keeps on disk: the experience log, learner checkpoints, and resuming.

The log (JSON lines) is the record of truth: each experiment is appended, flushed and fsynced
before the next one starts. Checkpoints (.npz, no pickle) are a convenience for users and a
cross-check; on restart the learner is rebuilt by replaying the log, which is exact because the
RLS update is a deterministic function of the example sequence.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from .predictors import PredictorBank

LOG_NAME = "experience.jsonl"
CHECKPOINT_NAME = "learner.npz"


class ExperienceLog:
    """Append-only JSON-lines file that survives a crash at any point."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.dropped_partial_line = False
        self.records = self._read_and_repair()

    def _read_and_repair(self) -> list[dict]:
        if not self.path.exists():
            return []
        data = self.path.read_bytes()
        records, good = [], 0
        for line in data.splitlines(keepends=True):
            if not line.endswith(b"\n"):
                break  # a line cut by a crash mid-write: not recorded, so not counted
            try:
                records.append(json.loads(line))
            except json.JSONDecodeError:
                break
            good += len(line)
        if good < len(data):
            self.dropped_partial_line = True
            with open(self.path, "r+b") as f:
                f.truncate(good)
        return records

    def __len__(self) -> int:
        return len(self.records)

    def append(self, record: dict) -> None:
        line = json.dumps(record, separators=(",", ":"), allow_nan=False) + "\n"
        with open(self.path, "a", encoding="utf-8") as f:
            f.write(line)
            f.flush()
            os.fsync(f.fileno())
        self.records.append(record)


def save_checkpoint(path: Path, bank: PredictorBank, experiments: int, **extra: float) -> None:
    """Atomic: write beside, then rename, so a crash never leaves half a checkpoint."""
    path = Path(path)
    tmp = path.with_name(path.stem + ".tmp.npz")
    arrays = bank.state_dict()
    arrays["experiments"] = np.array(experiments)
    for key, value in extra.items():
        arrays[key] = np.array(value)
    np.savez(tmp, **arrays)
    os.replace(tmp, path)


def load_checkpoint(path: Path) -> tuple[PredictorBank, int]:
    with np.load(Path(path), allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    return PredictorBank.from_state_dict(arrays), int(arrays["experiments"])


def replay(bank: PredictorBank, records: Iterable[dict]) -> int:
    """Learn every logged experiment again, in order; returns how many."""
    n = 0
    for record in records:
        bank.update(int(record["state"]), int(record["action_index"]), float(record["label"]))
        n += 1
    return n
