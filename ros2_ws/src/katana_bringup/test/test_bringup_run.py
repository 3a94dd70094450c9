"""katana-run: parameter YAML, node construction, backends, and the launch file's contents."""

from __future__ import annotations

import ast
import os
import sys
from pathlib import Path

import pytest
import rclpy
from katana_bringup import run
from rclpy.context import Context

SRC = Path(__file__).resolve().parents[2]


def test_load_params_merges_flattens_and_applies_wildcards(tmp_path):
    a = tmp_path / "a.yaml"
    a.write_text("/**:\n  ros__parameters:\n    use_sim_time: false\n"
                 "sim_node:\n  ros__parameters:\n    seed: 1\n    camera: {rate: 5.0}\n")
    b = tmp_path / "b.yaml"
    b.write_text("/sim_node:\n  ros__parameters:\n    seed: 7\n")
    params = run.load_params([a, b])
    assert params["sim_node"] == {"seed": 7, "camera.rate": 5.0}
    names = {p.name: p.value for p in run.overrides_for("sim_node", params)}
    assert names == {"use_sim_time": False, "seed": 7, "camera.rate": 5.0}
    bad = tmp_path / "bad.yaml"
    bad.write_text("sim_node:\n  seed: 1\n")
    with pytest.raises(ValueError, match="ros__parameters"):
        run.load_params([bad])


def test_default_yaml_holds_every_declared_parameter_of_its_nodes(tmp_path):
    params = run.load_params(run.default_params_files("sim"))
    assert {"sim_node", "pick_place_executor", "perception_node", "block_memory_node",
            "fovea_node", "curiosity_node"} <= params.keys()
    params["curiosity_node"]["run_dir"] = str(tmp_path / "run")
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        nodes = run.build_nodes("sim", params, ctx)
        assert len(nodes) == 6
        try:
            for node in nodes:
                builtin = {"use_sim_time", "start_type_description_service"}
                declared = set(node._parameters) - builtin
                assert declared == set(params[node.get_name()]), node.get_name()
        finally:
            for node in nodes:
                node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


def test_unknown_backend_and_missing_driver_fail_clearly(monkeypatch):
    with pytest.raises(ValueError, match="backend 'moon'"):
        run.build_nodes("moon", {}, None)
    monkeypatch.setitem(sys.modules, "katana_driver.bringup", None)  # import fails
    with pytest.raises(SystemExit, match="katana_driver"):
        run.build_nodes("hardware", {}, None)


def test_invalid_parameter_stops_construction_with_its_name():
    params = run.load_params(run.default_params_files("sim"))
    params["sim_node"]["num_blocks"] = 9
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        with pytest.raises(Exception, match="num_blocks"):
            run.build_nodes("sim", params, ctx)
    finally:
        rclpy.try_shutdown(context=ctx)


def test_main_runs_for_a_bounded_duration_and_rejects_bad_files(tmp_path, capsys):
    assert run.main(["--duration", "0.5", "--layers", "arm"]) == 0
    assert "sim_node, pick_place_executor" in capsys.readouterr().out
    missing = tmp_path / "nope.yaml"
    assert run.main(["--params", str(missing)]) == 2
    assert "cannot read parameters" in capsys.readouterr().err


def test_launch_file_starts_the_same_nodes_with_a_backend_argument():
    text = (SRC / "katana_bringup" / "launch" / "sim.launch.py").read_text()
    tree = ast.parse(text)
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call)]

    def kwargs(call):
        return {k.arg: k.value.value for k in call.keywords if isinstance(k.value, ast.Constant)}

    declared = {c.args[0].value: kwargs(c) for c in calls
                if getattr(c.func, "id", "") == "DeclareLaunchArgument"}
    assert declared["backend"]["default_value"] == "sim"
    nodes = {(kwargs(c)["package"], kwargs(c)["executable"]) for c in calls
             if getattr(c.func, "id", "") == "Node"}
    assert {("katana_sim", "sim_node"), ("katana_manipulation", "pick_place_executor"),
            ("katana_driver", "katana_driver_node"), ("katana_driver", "camera_node"),
            ("katana_perception", "perception_node"), ("katana_perception", "block_memory_node"),
            ("katana_perception", "fovea_node"), ("katana_curiosity", "curiosity_node")} <= nodes
    # every executable the launch file names is a console script of its package
    for pkg, exe in nodes:
        setup = (SRC / pkg / "setup.py").read_text()
        assert f'"{exe} = ' in setup, (pkg, exe)


def test_executables_are_installed_where_ros2_run_looks():
    prefix = os.environ.get("COLCON_PREFIX_PATH", "").split(os.pathsep)[0]
    if not prefix:
        pytest.skip("workspace not built/sourced (needs `make setup` and scripts/env.sh)")
    for pkg, exe in [("katana_sim", "sim_node"), ("katana_manipulation", "pick_place_executor"),
                     ("katana_bringup", "katana-run"), ("katana_bringup", "katana-demo"),
                     ("katana_perception", "perception_node"),
                     ("katana_perception", "block_memory_node"),
                     ("katana_perception", "fovea_node"), ("katana_curiosity", "curiosity_node"),
                     ("katana_curiosity", "katana-curiosity"),
                     ("katana_driver", "katana_driver_node"), ("katana_driver", "camera_node")]:
        path = Path(prefix) / pkg / "lib" / pkg / exe
        assert path.is_file() and os.access(path, os.X_OK), path
