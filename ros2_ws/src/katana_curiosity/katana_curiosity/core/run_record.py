"""What a robot run keeps on disk: the experience log, learner checkpoints, and resuming.

The log (JSON lines, one `ExperimentRecord` each) is the record of truth: each experiment is
appended, flushed and fsynced before the next one starts. Checkpoints (.npz, no pickle) are a
convenience for users and a cross-check; on restart the learner is rebuilt by replaying the
log, which is exact because the RLS update is a deterministic function of the example sequence.

Reading never loses a valid record and never rewrites anything silently: a line cut by a crash
mid-write (the last line, without its newline) is moved aside to `<log>.corrupt` and reported;
any other bad line stops the reading with one message naming the file, the line and the field,
unless the caller asked to quarantine bad lines: then they go to `<log>.quarantine`, the whole
original log is kept as `<log>.before-quarantine`, and the log goes on without them. A
checkpoint the log cannot reproduce (or cannot be read) is moved aside, never overwritten.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import zipfile
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from .predictors import PredictorBank

LOG_NAME = "experience.jsonl"
CHECKPOINT_NAME = "learner.npz"
MODES = ("query", "plan", "random")


class LogError(ValueError):
    """A record of the experience log is invalid; the message names file, line and field."""


class RecordError(ValueError):
    """One record is invalid: `field_name` and why."""

    def __init__(self, field_name: str, reason: str) -> None:
        super().__init__(f"field '{field_name}': {reason}")
        self.field_name = field_name


@dataclass(frozen=True)
class InstanceRecord:
    """The fovea instance that was executed (pixel position, the five bits, the placement)."""

    pixel_u: float
    pixel_v: float
    bits: list[bool]
    features: list[float]
    support_ids: list[str]
    placement: list[float]  # x, y, z of the placement point in the world frame, m
    turn_rad: float = 0.0  # the block placed turned by this against the fovea (the block below)


@dataclass(frozen=True)
class ExperimentRecord:
    """One experiment as the log keeps it (written by the robot loop, read by `replay`)."""

    index: int  # 0-based, contiguous over the whole run
    state: int  # height placed upon
    action: int  # 1-based action (bits on + 1)
    label: int  # +1 stable, -1 fell
    mode: str  # query, plan or random
    setting: int = 0  # the paper's setting counter i (settings observed, drops included)
    available: list[int] = field(default_factory=list)  # states the setting offered
    moved_block: str = ""
    attempts: int = 1  # pick-and-place goals sent (missed grasps are retried)
    instance: InstanceRecord | None = None
    margin_before: float = 0.0
    confidence_before: float = 0.0
    weights_before: list[float] = field(default_factory=list)
    weights_after: list[float] = field(default_factory=list)
    stage_s: dict[str, float] = field(default_factory=dict)  # wall seconds per stage
    dropped_before: dict[str, int] = field(default_factory=dict)  # attempts dropped, by reason
    wall_time: float = 0.0  # seconds since the epoch when it was logged
    resets_before: int = 0  # world resets since the previous experiment
    unknown_offered: int = -1  # offered (height, action) pairs still unknown; -1: not recorded
    offer: list[list[int]] = field(default_factory=list)  # [height, 1-based action] pairs offered

    @property
    def action_index(self) -> int:
        return self.action - 1

    def to_json(self) -> str:
        data = asdict(self)
        data["action_index"] = self.action_index  # for readers of the raw log
        return json.dumps(data, separators=(",", ":"), allow_nan=False)

    @classmethod
    def from_mapping(cls, data: Any) -> ExperimentRecord:
        """Validate one parsed JSON record; RecordError names the first bad field."""
        if not isinstance(data, Mapping):
            raise RecordError("(record)", "is not a JSON object")
        known = {f.name for f in fields(cls)} | {"action_index"}
        unknown = sorted(set(data) - known)
        if unknown:
            raise RecordError(unknown[0], "is not a field of an experiment record")
        for name in ("index", "state", "action", "label", "mode"):
            if name not in data:
                raise RecordError(name, "is missing")
        values = {
            "index": _int(data, "index", 0),
            "state": _int(data, "state", 0),
            "action": _int(data, "action", 1),
            "label": _int(data, "label"),
            "mode": data["mode"],
            "setting": _int(data, "setting", 0, default=0),
            "available": [_int({"available": v}, "available", 0) for v in
                          _list(data, "available")],
            "moved_block": _str(data, "moved_block"),
            "attempts": _int(data, "attempts", 0, default=1),
            "instance": _instance(data.get("instance")),
            "margin_before": _float(data, "margin_before"),
            "confidence_before": _float(data, "confidence_before"),
            "weights_before": _floats(data, "weights_before"),
            "weights_after": _floats(data, "weights_after"),
            "stage_s": _float_map(data, "stage_s"),
            "dropped_before": _count_map(data, "dropped_before"),
            "wall_time": _float(data, "wall_time"),
            "resets_before": _int(data, "resets_before", 0, default=0),
            "unknown_offered": _int(data, "unknown_offered", -1, default=-1),
            "offer": _pairs(data, "offer"),
        }
        if values["label"] not in (-1, 1):
            raise RecordError("label", f"{values['label']!r} is not +1 or -1")
        if values["mode"] not in MODES:
            raise RecordError("mode", f"{values['mode']!r} is not one of {', '.join(MODES)}")
        if "action_index" in data and data["action_index"] != values["action"] - 1:
            raise RecordError("action_index", f"{data['action_index']!r} is not action - 1")
        return cls(**values)


# -- field checks --------------------------------------------------------------------------


def _int(data: Mapping, name: str, low: int | None = None, default: int | None = None) -> int:
    value = data.get(name, default)
    if isinstance(value, bool) or not isinstance(value, int):
        raise RecordError(name, f"{value!r} is not an integer")
    if low is not None and value < low:
        raise RecordError(name, f"{value!r} is below {low}")
    return value


def _pairs(data: Mapping, name: str) -> list[list[int]]:
    """[height >= 0, action >= 1] pairs."""
    pairs = []
    for item in _list(data, name):
        if not isinstance(item, list) or len(item) != 2:
            raise RecordError(name, f"{item!r} is not a [height, action] pair")
        pairs.append([_int({name: item[0]}, name, 0), _int({name: item[1]}, name, 1)])
    return pairs


def _float(data: Mapping, name: str) -> float:
    value = data.get(name, 0.0)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise RecordError(name, f"{value!r} is not a finite number")
    return float(value)


def _str(data: Mapping, name: str) -> str:
    value = data.get(name, "")
    if not isinstance(value, str):
        raise RecordError(name, f"{value!r} is not text")
    return value


def _list(data: Mapping, name: str) -> list:
    value = data.get(name, [])
    if not isinstance(value, list):
        raise RecordError(name, f"{value!r} is not a list")
    return value


def _floats(data: Mapping, name: str) -> list[float]:
    return [_float({name: v}, name) for v in _list(data, name)]


def _float_map(data: Mapping, name: str) -> dict[str, float]:
    value = data.get(name, {})
    if not isinstance(value, Mapping):
        raise RecordError(name, f"{value!r} is not an object")
    return {str(k): _float({f"{name}.{k}": v}, f"{name}.{k}") for k, v in value.items()}


def _count_map(data: Mapping, name: str) -> dict[str, int]:
    value = data.get(name, {})
    if not isinstance(value, Mapping):
        raise RecordError(name, f"{value!r} is not an object")
    return {str(k): _int({f"{name}.{k}": v}, f"{name}.{k}", 0) for k, v in value.items()}


def _instance(value: Any) -> InstanceRecord | None:
    if value is None:
        return None
    if not isinstance(value, Mapping):
        raise RecordError("instance", f"{value!r} is not an object")
    try:
        bits = _list(value, "bits")
        if not all(isinstance(b, bool) for b in bits):
            raise RecordError("bits", "entries must be true or false")
        ids = _list(value, "support_ids")
        if not all(isinstance(i, str) for i in ids):
            raise RecordError("support_ids", "entries must be text")
        placement = _floats(value, "placement")
        if len(placement) != 3:
            raise RecordError("placement", f"needs x, y, z, got {len(placement)} values")
        return InstanceRecord(_float(value, "pixel_u"), _float(value, "pixel_v"), bits,
                              _floats(value, "features"), ids, placement,
                              _float(value, "turn_rad"))  # older logs: none, 0
    except RecordError as err:
        raise RecordError(f"instance.{err.field_name}", str(err).split(": ", 1)[1]) from None


# -- the log -------------------------------------------------------------------------------


class ExperienceLog:
    """Append-only JSON-lines file of ExperimentRecords that survives a crash at any point."""

    def __init__(self, path: Path, quarantine_bad_lines: bool = False) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.quarantine_bad_lines = quarantine_bad_lines
        #: set when a torn last line was moved aside: where to, and how many bytes
        self.moved_aside: tuple[Path, int] | None = None
        #: set when bad lines were quarantined: (line number, reason) each
        self.quarantined: list[tuple[int, str]] = []
        #: where the quarantined lines and the whole original log went
        self.quarantine_path: Path | None = None
        self.original_path: Path | None = None
        self.records: list[ExperimentRecord] = self._read()

    def _read(self) -> list[ExperimentRecord]:
        if not self.path.exists():
            return []
        data = self.path.read_bytes()
        records: list[ExperimentRecord] = []
        bad: list[tuple[int, bytes, str]] = []  # quarantined: line number, raw line, reason
        good = 0
        lines = data.splitlines(keepends=True)
        for number, line in enumerate(lines, start=1):
            if not line.endswith(b"\n") and number == len(lines):
                self._move_aside(data, good)  # cut by a crash mid-write: never recorded
                break
            try:
                record = self._parse(line, expected=len(records) + len(bad))
            except RecordError as err:
                if not self.quarantine_bad_lines:
                    raise LogError(f"{self.path}:{number}: {err}") from None
                bad.append((number, line, str(err)))
            else:  # after a quarantined line the index goes on from the last kept record
                records.append(record if not bad else _renumbered(record, len(records)))
            good += len(line)
        if bad:
            self._quarantine(bad, records, data)
        return records

    @staticmethod
    def _parse(line: bytes, expected: int) -> ExperimentRecord:
        try:
            parsed = json.loads(line)
        except ValueError as exc:  # JSONDecodeError and UnicodeDecodeError
            detail = getattr(exc, "msg", None) or type(exc).__name__
            raise RecordError("(record)", f"not a JSON record ({detail})") from None
        record = ExperimentRecord.from_mapping(parsed)
        if record.index != expected:
            what = "a duplicate" if record.index < expected else "a gap"
            raise RecordError("index", f"{record.index} is {what} (expected {expected})")
        return record

    def _quarantine(self, bad: list[tuple[int, bytes, str]], records: list[ExperimentRecord],
                    original: bytes) -> None:
        """The bad lines to `<log>.quarantine` (raw, in order), the whole log as it was to
        `<log>.before-quarantine`, then the log rewritten without them, atomically."""
        self.original_path = _free_name(self.path, ".before-quarantine")
        self.quarantine_path = _free_name(self.path, ".quarantine")
        _write_synced(self.original_path, original)
        _write_synced(self.quarantine_path, b"".join(line if line.endswith(b"\n") else line + b"\n"
                                                     for _, line, _ in bad))
        tmp = self.path.with_name(self.path.name + ".tmp")
        _write_synced(tmp, "".join(r.to_json() + "\n" for r in records).encode())
        os.replace(tmp, self.path)
        self.quarantined = [(number, reason) for number, _, reason in bad]

    def _move_aside(self, data: bytes, good: int) -> None:
        aside = _free_name(self.path, ".corrupt")
        aside.write_bytes(data[good:])
        with open(self.path, "r+b") as f:
            f.truncate(good)
            os.fsync(f.fileno())
        self.moved_aside = (aside, len(data) - good)

    def __len__(self) -> int:
        return len(self.records)

    def append(self, record: ExperimentRecord) -> None:
        """Write, flush and fsync one record; OSError (disk full, folder gone) propagates."""
        if record.index != len(self.records):
            raise ValueError(f"record index {record.index}, expected {len(self.records)}")
        line = record.to_json() + "\n"
        with open(self.path, "a", encoding="utf-8") as f:
            f.write(line)
            f.flush()
            os.fsync(f.fileno())
        self.records.append(record)


def _free_name(path: Path, suffix: str, extension: str = "") -> Path:
    """`<path><suffix><extension>`, or with .2, .3, ... before the extension if taken: a file
    moved aside never replaces another."""
    aside = path.with_name(path.name + suffix + extension)
    n = 1
    while aside.exists():
        n += 1
        aside = path.with_name(f"{path.name}{suffix}.{n}{extension}")
    return aside


def _write_synced(path: Path, data: bytes) -> None:
    with open(path, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def _renumbered(record: ExperimentRecord, index: int) -> ExperimentRecord:
    return dataclasses.replace(record, index=index)


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


def replay(bank: PredictorBank, records: Iterable[ExperimentRecord], source: str = "log") -> int:
    """Learn every logged experiment again, in order; returns how many.

    LogError (naming `source`, the line and the field) when a record's state is not one the
    bank learns or its action is not one of the bank's actions; nothing is learned then.
    """
    records = list(records)
    heights = {h for h in range(len(bank.slot)) if bank.slot[h] >= 0}
    for number, record in enumerate(records, start=1):
        if record.state not in heights:
            raise LogError(f"{source}:{number}: field 'state': {record.state} is not one of "
                           f"the learned heights {sorted(heights)}")
        if not 0 <= record.action_index < bank.n_actions:
            raise LogError(f"{source}:{number}: field 'action': {record.action} is not in "
                           f"1..{bank.n_actions}")
    for record in records:
        bank.update(record.state, record.action_index, float(record.label))
    return len(records)


class CheckpointError(ValueError):
    """A checkpoint file cannot be read; the message says what is wrong with it."""


def read_checkpoint(path: Path) -> tuple[PredictorBank, int]:
    """load_checkpoint with the true reason when it fails (np.load alone calls any non-zip
    file "pickled data")."""
    path = Path(path)
    try:
        with zipfile.ZipFile(path) as archive:
            damaged = archive.testzip()
            names = archive.namelist()
    except zipfile.BadZipFile:
        raise CheckpointError("not an .npz archive (not a zip file: cut short or overwritten)"
                              ) from None
    except OSError as exc:
        raise CheckpointError(f"cannot be read ({exc.strerror or exc})") from None
    if damaged is not None:
        raise CheckpointError(f"its array {damaged!r} is damaged (CRC mismatch)")
    missing = sorted({"experiments.npy", "w.npy", "a_inv.npy", "heights.npy"} - set(names))
    if missing:
        raise CheckpointError(f"has no array {missing[0].removesuffix('.npy')!r}")
    try:
        return load_checkpoint(path)
    except (ValueError, KeyError, TypeError) as exc:
        raise CheckpointError(f"its arrays do not make a learner ({exc})") from None


@dataclass(frozen=True)
class CheckpointVerdict:
    """What resuming did with a checkpoint: `aside` is where it was moved (None: kept), and
    `message` says why, for the user (None: nothing to say)."""

    aside: Path | None = None
    message: str | None = None


def check_checkpoint(path: Path, records: list[ExperimentRecord], make_bank) -> CheckpointVerdict:
    """Keep the checkpoint if the log reproduces it (it is the learner after its first
    `experiments` records: a cache at most one experiment behind after a crash); otherwise move
    it aside, never to be overwritten, under a name that says why. `make_bank()` gives an
    untrained bank for the replay."""
    path = Path(path)
    if not path.exists():
        return CheckpointVerdict()
    try:
        saved, experiments = read_checkpoint(path)
    except CheckpointError as exc:
        aside = _free_name(path.with_suffix(""), ".unreadable", ".npz")
        os.replace(path, aside)
        return CheckpointVerdict(aside, f"the checkpoint {path} {exc}; moved it to {aside}; "
                                 "the learner is rebuilt from the log")
    prefix = make_bank()
    if experiments <= len(records):
        replay(prefix, records[:experiments])
        if saved.w.shape == prefix.w.shape and np.allclose(saved.w, prefix.w, atol=1e-9):
            return CheckpointVerdict()
        why = f"its learner is not the log's after {experiments} experiments"
    else:
        why = f"it has {experiments} experiments, the log {len(records)}"
    aside = _free_name(path.with_suffix(""), f".not-the-log-{experiments}-experiments", ".npz")
    os.replace(path, aside)
    return CheckpointVerdict(aside, (
        f"the checkpoint {path} disagrees with the log ({why}): the run goes on from the log "
        f"(a run resumes only from its log: every experiment's record; a checkpoint holds "
        f"only a learner). The checkpoint was moved to {aside}; to use its learner, load it as "
        f"a model: katana-robot skill --model {aside}"))
