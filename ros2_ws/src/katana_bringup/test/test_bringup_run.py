"""katana-run: parameter YAML, node construction, backends, and the launch file's contents."""

from __future__ import annotations

import ast
import importlib.util
import os
import sys
import types
from pathlib import Path

import pytest
import rclpy
from katana_bringup import demo, run
from katana_common.params import ParameterError
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
    assert {"sim_node", "frame_publisher", "pick_place_executor", "perception_node",
            "block_memory_node", "fovea_node", "curiosity_node"} <= params.keys()
    # the scene, the pick-and-place geometry and the clock once, for every node
    assert set(params["/**"]) == {"world_frame", "block_size", "camera_position", "camera_rpy",
                                  "approach_height", "grasp_offset", "use_sim_time"}
    assert params["/**"]["use_sim_time"] is True
    assert run.load_params(run.default_params_files("hardware"))["/**"]["use_sim_time"] is False
    params["curiosity_node"]["run_dir"] = str(tmp_path / "run")
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        nodes = run.build_nodes("sim", params, ctx, record=tmp_path / "run.mcap")
        assert len(nodes) == 8
        try:
            for node in nodes:
                builtin = {"use_sim_time", "start_type_description_service"}
                declared = set(node._parameters) - builtin
                name = node.get_name()
                assert node.get_parameter("use_sim_time").value is True, name
                # nothing in the YAML is ignored: every key is a declared parameter
                assert set(params.get(name, {})) <= declared, name
                if name in ("perception_node", "block_memory_node", "fovea_node",
                            "frame_publisher"):
                    # every parameter it declares is set: in its section or under /**
                    assert declared <= set(params[name]) | set(params["/**"]), name
                    assert {"world_frame", "block_size", "camera_position",
                            "camera_rpy"} <= declared, name
        finally:
            for node in nodes:
                node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


def test_shared_yaml_names_no_backend_node():
    text = (SRC / "katana_bringup" / "config" / "graph.yaml").read_text()
    assert "sim_node" not in text and "katana_driver_node" not in text


def test_params_overlay_the_packaged_yaml_and_unknown_names_stop(tmp_path, capsys):
    overlay = tmp_path / "overlay.yaml"
    overlay.write_text("fovea_node:\n  ros__parameters:\n    max_height: 2\n")
    parser = run.argparse.ArgumentParser(prog="katana-run")
    files, params = run.load_graph_params(parser, "sim", [overlay])
    assert files[-1] == overlay and params["fovea_node"]["max_height"] == 2
    assert params["fovea_node"]["fovea_size_px"] == 40  # the packaged values stay
    assert params["sim_node"]["num_blocks"] == 4
    typo = tmp_path / "typo.yaml"
    typo.write_text("fovea_nod:\n  ros__parameters:\n    max_height: 2\n")
    with pytest.raises(SystemExit) as stop:
        run.load_graph_params(parser, "sim", [typo])
    assert stop.value.code == 2
    assert "fovea_nod" in capsys.readouterr().err
    params["fovea_node"]["max_stat"] = 2  # a mistyped key stops the node, naming it
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        with pytest.raises(ParameterError, match="max_stat"):
            run.build_nodes("sim", params, ctx, layers=["perception"])
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
    assert "sim_node, frame_publisher, pick_place_executor" in capsys.readouterr().out
    bad = [
        (["--params", str(tmp_path / "nope.yaml")], "--params"),
        (["--duration", "-1"], "--duration"),
        (["--duration", "nan"], "--duration"),
        (["--record", str(tmp_path / "no" / "such" / "dir" / "x.mcap")], "--record"),
        (["--record", str(tmp_path / "x.bag")], "--record"),
        (["--layers", "arm,moon"], "--layers"),
        (["--backend", "moon"], "--backend"),
        (["--bogus"], "--bogus"),
    ]
    for argv, option in bad:
        with pytest.raises(SystemExit) as stop:
            run.main(argv)
        err = capsys.readouterr().err
        assert stop.value.code == 2, argv
        assert "usage: katana-run" in err and option in err.splitlines()[-1], (argv, err)


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
             if getattr(c.func, "id", "") in ("Node", "LifecycleNode") and "package" in kwargs(c)}
    nodes |= {(t.elts[0].value, t.elts[1].value) for t in ast.walk(tree)
              if isinstance(t, ast.Tuple) and len(t.elts) == 2
              and all(isinstance(e, ast.Constant) and isinstance(e.value, str) for e in t.elts)
              and t.elts[0].value.startswith("katana_")}
    assert {("katana_sim", "sim_node"), ("katana_manipulation", "pick_place_executor"),
            ("katana_driver", "katana_driver_node"), ("katana_camera", "camera_node"),
            ("katana_perception", "perception_node"), ("katana_perception", "block_memory_node"),
            ("katana_perception", "fovea_node"), ("katana_curiosity", "curiosity_node"),
            ("katana_description", "frame_publisher")} <= nodes
    assert declared["frames"]["default_value"] == "katana"
    # every executable the launch file names is a console script of its package (the viewers'
    # and frames:=robot_state_publisher's full-install packages: test_viewer_configs)
    for pkg, exe in ((p, e) for p, e in nodes if p.startswith("katana_")):
        setup = (SRC / pkg / "setup.py").read_text()
        assert f'"{exe} = ' in setup, (pkg, exe)
    # the same parameter files as katana-run, in the same order
    assert "default_params_files(backend)" in text


@pytest.mark.parametrize("path", ["katana_bringup/launch/sim.launch.py",
                                  "katana_driver/launch/katana_hardware.launch.py"])
def test_launch_files_start_the_driver_as_a_lifecycle_node(path):
    """launch_ros's LifecycleNode (its name and namespace given, as it requires); the node's
    own autostart brings it to active, so no launch file emits a transition of its own."""
    tree = ast.parse((SRC / path).read_text())
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call)]
    drivers = [c for c in calls if getattr(c.func, "id", "") == "LifecycleNode"]
    assert len(drivers) == 1
    keywords = {k.arg for k in drivers[0].keywords}
    assert {"package", "executable", "name", "namespace", "parameters"} <= keywords
    assert not [c for c in calls if getattr(c.func, "id", "") in ("ChangeState", "EmitEvent")]


def _launch_module(monkeypatch, path: Path):
    """A launch file imported with stand-ins for launch and launch_ros (not on PyPI): each
    Node(...) is the dict of its keyword arguments."""
    fakes = {name: types.ModuleType(name) for name in (
        "launch", "launch.actions", "launch.substitutions", "launch_ros", "launch_ros.actions")}
    fakes["launch"].LaunchDescription = list
    fakes["launch.actions"].DeclareLaunchArgument = fakes["launch.actions"].OpaqueFunction = (
        lambda *a, **k: (a, k))
    fakes["launch.substitutions"].LaunchConfiguration = lambda name: name
    fakes["launch_ros.actions"].Node = lambda **kwargs: kwargs
    fakes["launch_ros.actions"].LifecycleNode = lambda **kwargs: kwargs
    for name, module in fakes.items():
        monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location(path.stem.replace(".", "_"), path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_launch_frames_robot_state_publisher_gets_the_same_urdf(monkeypatch, tmp_path):
    launch = _launch_module(monkeypatch, SRC / "katana_bringup" / "launch" / "sim.launch.py")
    overlay = tmp_path / "overlay.yaml"
    overlay.write_text("frame_publisher:\n  ros__parameters:\n    model: 300_6m180\n")
    files = [str(f) for f in run.default_params_files("sim")] + [str(overlay)]
    (own,) = launch._frame_nodes("katana", files)
    assert (own["executable"], own["parameters"]) == ("frame_publisher", files)
    rsp, scene = launch._frame_nodes("robot_state_publisher", files)
    assert rsp["executable"] == "robot_state_publisher"
    (params,) = rsp["parameters"]
    assert params["robot_description"] == (
        SRC / "katana_description" / "urdf" / "katana_300_6m180.urdf").read_text()
    assert params["use_sim_time"] is True  # the sim's clock, as every node of the graph
    assert scene["executable"] == "frame_publisher"
    assert scene["parameters"] == [*files, {"robot_frames": False}]


def test_executables_are_installed_where_ros2_run_looks():
    prefix = os.environ.get("COLCON_PREFIX_PATH", "").split(os.pathsep)[0]
    if not prefix:
        pytest.skip("workspace not built/sourced (needs `make setup` and scripts/env.sh)")
    for pkg, exe in [("katana_sim", "sim_node"), ("katana_manipulation", "pick_place_executor"),
                     ("katana_bringup", "katana-run"), ("katana_bringup", "katana-demo"),
                     ("katana_bringup", "foxglove_bridge"),
                     ("katana_perception", "perception_node"),
                     ("katana_perception", "block_memory_node"),
                     ("katana_perception", "fovea_node"), ("katana_curiosity", "curiosity_node"),
                     ("katana_paper", "katana-curiosity"), ("katana_paper", "katana-robot"),
                     ("katana_driver", "katana_driver_node"), ("katana_camera", "camera_node"),
                     ("katana_description", "frame_publisher")]:
        path = Path(prefix) / pkg / "lib" / pkg / exe
        assert path.is_file() and os.access(path, os.X_OK), path


@pytest.mark.parametrize(
    "args, option",
    [
        (["--experiments", "0"], "--experiments"),
        (["--out", "/proc/no/such/folder"], "--out"),
        (["--timeout", "-1"], "--timeout"),
        (["--seed", "-2"], "--seed"),
    ],
)
def test_katana_demo_checks_every_option_before_any_work(capsys, args, option):
    """One line naming the option, the usage, exit 2; no graph is started (katana-robot's
    options: katana_paper's test_paper_robot)."""
    with pytest.raises(SystemExit) as exit_info:
        demo.main(args)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert f"error: argument {option}" in err and "usage: katana-demo" in err
