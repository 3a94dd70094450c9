"""A short soak of curiosity_node against the fake graph (curiosity_graph.py): what it writes and
keeps per experiment does not grow with the run. The log is appended to, one line per
experiment, never rewritten; the checkpoint is the same size at every save (the learner's
state, not the log); and apart from the log's records no container the node keeps grows.
The long run on the simulated arm is bench/bench_soak.py."""

import builtins
import sys
from pathlib import Path

import numpy as np
from katana_curiosity import curiosity_node
from katana_curiosity.core import run_record

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib
from curiosity_graph import Graph, read_log  # noqa: E402

EXPERIMENTS = 40
COMPARED_AT = (10, EXPERIMENTS)  # container sizes are taken after these experiments


class _CountingFile:
    """A file object that counts the bytes written through it."""

    def __init__(self, f, on_write) -> None:
        self._f, self._on_write = f, on_write

    def write(self, data):
        self._on_write(len(data.encode() if isinstance(data, str) else data))
        return self._f.write(data)

    def __getattr__(self, name):
        return getattr(self._f, name)

    def __enter__(self):
        self._f.__enter__()
        return self

    def __exit__(self, *exc):
        return self._f.__exit__(*exc)


def container_sizes(root, skip: set[str], depth: int = 4) -> dict[str, int]:
    """len() of every list, dict, set, tuple and array reachable through the attributes of the
    project's objects from `root` (paths named as attribute chains), `skip` left out."""
    sizes: dict[str, int] = {}
    seen: set[int] = set()

    def walk(obj, path: str, level: int) -> None:
        if id(obj) in seen or path in skip:
            return
        seen.add(id(obj))
        if isinstance(obj, (list, dict, set, tuple, np.ndarray)):
            sizes[path] = obj.size if isinstance(obj, np.ndarray) else len(obj)
            items = obj.items() if isinstance(obj, dict) else ()
            for key, value in items:
                walk(value, f"{path}[{key!r}]", level - 1)
            return
        if level <= 0 or not type(obj).__module__.startswith("katana_curiosity"):
            return
        for name, value in vars(obj).items() if hasattr(obj, "__dict__") else ():
            walk(value, f"{path}.{name}", level - 1)

    walk(root, "node", depth)
    return sizes


def test_log_and_checkpoint_writes_and_the_node_s_state_do_not_grow_with_the_run(
        tmp_path, monkeypatch) -> None:
    log_writes: list[tuple[str, int]] = []  # (mode, bytes) of every write to the log
    checkpoint_bytes: list[int] = []
    sizes: dict[int, dict[str, int]] = {}
    node_ref: list = []

    def counting_open(file, mode="r", *args, **kwargs):
        f = builtins.open(file, mode, *args, **kwargs)
        if Path(file).name == run_record.LOG_NAME and any(c in mode for c in "wax+"):
            return _CountingFile(f, lambda n: log_writes.append((mode, n)))
        return f

    save = curiosity_node.save_checkpoint

    def measured_save(path, bank, experiments, **extra):
        save(path, bank, experiments, **extra)
        checkpoint_bytes.append(Path(path).stat().st_size)
        if experiments in COMPARED_AT and node_ref:
            sizes[experiments] = container_sizes(node_ref[0], skip={"node.log.records"})

    monkeypatch.setattr(run_record, "open", counting_open, raising=False)
    monkeypatch.setattr(curiosity_node, "save_checkpoint", measured_save)
    with Graph(tmp_path, EXPERIMENTS) as g:
        node_ref.append(g.node)
        g.wait(g.node.finished.is_set, 60.0, "the experiment loop finishing")
    lines = (tmp_path / run_record.LOG_NAME).read_bytes().splitlines(keepends=True)
    assert len(read_log(tmp_path)) == EXPERIMENTS
    # one append per experiment, of exactly its line: nothing before it is written again
    assert [mode for mode, _ in log_writes] == ["a"] * EXPERIMENTS
    assert [n for _, n in log_writes] == [len(line) for line in lines]
    # the checkpoint holds the learner (fixed shapes), whatever the log's length
    assert len(checkpoint_bytes) == EXPERIMENTS
    assert len(set(checkpoint_bytes)) == 1, checkpoint_bytes
    # the node keeps nothing per experiment beyond the log's records: a container that varies
    # with the scene (the instances of a setting) stays within bounds, one that keeps a thing
    # per experiment grows by about one per experiment
    early, late = (sizes[n] for n in COMPARED_AT)
    assert len(early) > 20  # the walk reached the loop, the environment, the explorer
    per_experiment = 0.5 * (COMPARED_AT[1] - COMPARED_AT[0])
    grown = {k: (early.get(k, 0), v) for k, v in late.items()
             if v - early.get(k, 0) >= per_experiment}
    assert not grown, f"containers grew from experiment {COMPARED_AT[0]} to {EXPERIMENTS}: {grown}"
    assert late.get("node.log.records") is None  # left out: the log itself
