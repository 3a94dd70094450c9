"""katana-demo's terminal: one line per experiment (and a bar on a terminal), the nodes' log
lines in the run folder's nodes.log unless --verbose; seen as a user sees it (the installed
console script, its standard streams)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess

from katana_bringup.terminal import NODES_LOG_NAME, experiment_line
from katana_common.testing import private_ros_env

ROS_LINE = re.compile(r"^\[(INFO|WARN|ERROR)\] \[\d+\.\d+\] \[(\w+)\]: ")


def _demo(tmp_path, *extra: str) -> tuple[subprocess.CompletedProcess, list[dict]]:
    assert shutil.which("katana-demo"), "katana-demo is not installed (make setup)"
    out = tmp_path / "run"
    proc = subprocess.run(["katana-demo", "--experiments", "3", "--out", str(out), *extra],
                          capture_output=True, text=True, timeout=240, env=private_ros_env())
    assert proc.returncode == 0, proc.stderr[-2000:]
    records = [json.loads(line) for line in (out / "experience.jsonl").read_text().splitlines()]
    return proc, records


def test_the_terminal_shows_one_line_per_experiment_and_the_nodes_log_goes_to_a_file(tmp_path):
    proc, records = _demo(tmp_path)
    lines = proc.stderr.splitlines()
    expected = [experiment_line(r["index"], r["mode"], r["state"], r["action"], r["label"],
                                r["moved_block"]) for r in records]
    assert [line for line in lines if line.startswith("#")] == expected
    assert not [line for line in lines if ROS_LINE.match(line)], proc.stderr
    log = (tmp_path / "run" / NODES_LOG_NAME).read_text().splitlines()
    nodes = {m.group(2) for line in log if (m := ROS_LINE.match(line))}
    assert {"sim_node", "curiosity_node", "pick_place_executor"} <= nodes
    assert sum(": experiment " in line for line in log) == len(records) == 3
    assert f"the nodes' log: {tmp_path / 'run' / NODES_LOG_NAME}" in proc.stdout


def test_verbose_keeps_the_nodes_log_on_the_terminal(tmp_path):
    proc, records = _demo(tmp_path, "--verbose")
    assert not (tmp_path / "run" / NODES_LOG_NAME).exists()
    assert sum(bool(ROS_LINE.match(line)) and ": experiment " in line
               for line in proc.stderr.splitlines()) == len(records)
