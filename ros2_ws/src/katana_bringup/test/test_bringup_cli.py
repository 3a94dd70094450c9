"""Every bad command line of katana-demo, katana-run and katana-emulator is refused before any
work: exit 2, the usage, one line naming the option (or the file, line and key of a --params
file), no traceback, and the working folder unchanged. Property-based over each option's bad
values, in-process (main(argv) with a temporary folder as the working folder); a few through
the installed console scripts."""

from __future__ import annotations

import math
import os
import shutil
import subprocess

import pytest
import rclpy
import yaml
from hypothesis import given
from hypothesis import strategies as st
from katana_bringup import demo, graph_params, run
from katana_common.cli_args import parse_command_line
from katana_common.cli_testing import (
    BAD_WORKING_TREE,
    bad_working_folder,
    cli_settings,
    floats_outside,
    folders,
    ints_outside,
    mcaps,
    missing_files,
    names,
    not_one_of,
    refused,
    tree,
    unknown_flags,
    unwritable_files,
    words,
)
from katana_common.param_files import TOLERATED_UNDECLARED
from katana_curiosity.core.strategies import STRATEGIES
from katana_emulator import emulator
from katana_perception.core.calibration import Calibration

CHECKS = cli_settings(25)


DEMO_OPTIONS = {
    "--experiments": ints_outside(1, 10_000_000),
    "--seed": ints_outside(0, 2**31 - 1),
    "--strategy": not_one_of(STRATEGIES),
    "--backend": not_one_of(graph_params.BACKENDS),
    "--real-time-factor": floats_outside(0.0, 100.0),
    "--timeout": floats_outside(0.0, low_open=True),
    "--out": folders,
    "--record": mcaps,
    "--params": missing_files,
    "--contact-sheet": unwritable_files(".png"),
    "--contact-first": ints_outside(0),
}
RUN_OPTIONS = {
    "--backend": not_one_of(graph_params.BACKENDS),
    "--layers": not_one_of(graph_params.LAYERS)
    | st.sampled_from([",", "arm,moon", ""]),
    "--duration": floats_outside(0.0, low_open=True),
    "--record": mcaps,
    "--params": missing_files,
}
EMULATOR_OPTIONS = {
    "--port": ints_outside(0, 65535),
    "--type": st.integers().filter(lambda v: v not in (300, 400, 450)).map(str) | words
    | st.sampled_from(["450.0"]),
    "--variant": not_one_of(("6M180", "6M90A", "6M90B")),
    "--time-scale": floats_outside(0.0, 1000.0, low_open=True),
    "--calibration-time": floats_outside(0.0, 3600.0),
    "--latency": floats_outside(0.0, 60.0),
    "--spline-latency": floats_outside(0.0, 60.0),
    "--silent-rate": floats_outside(0.0, 1.0),
    "--corrupt-rate": floats_outside(0.0, 1.0),
    "--block-width-m": floats_outside(0.005, 0.099),
    "--seed": words,
    "--host": st.sampled_from(["", "bad..host", "no-such-host.invalid"]),
}


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    """A working folder with a file and a folder named like the bad values' targets; the work
    of each tool replaced by a failure, so that a command line let through cannot start it."""
    monkeypatch.chdir(tmp_path)
    bad_working_folder(tmp_path)

    def work(*_a, **_k):
        raise AssertionError("the work started")

    monkeypatch.setattr(rclpy, "init", work)
    monkeypatch.setattr(emulator, "KatanaEmulator", work)
    return tmp_path


def _refused(main, argv, option, capsys, folder):
    before = tree(folder)
    line = refused(main, argv, capsys)
    assert option in line, (argv, line)
    assert tree(folder) == before, argv
    return line


@CHECKS
@given(data=st.data())
@pytest.mark.parametrize("main, options", [(demo.main, DEMO_OPTIONS), (run.main, RUN_OPTIONS),
                                           (emulator.main, EMULATOR_OPTIONS)],
                         ids=["katana-demo", "katana-run", "katana-emulator"])
def test_a_bad_value_of_any_option_is_refused_naming_it(workdir, capsys, data, main, options):
    option = data.draw(st.sampled_from(sorted(options)))
    value = data.draw(options[option])
    _refused(main, [f"{option}={value}"], option, capsys, workdir)


@CHECKS
@given(data=st.data())
@pytest.mark.parametrize("tool", [demo, run, emulator],
                         ids=["katana-demo", "katana-run", "katana-emulator"])
def test_an_unknown_option_is_refused(workdir, capsys, data, tool):
    main, parser = tool.main, tool.build_parser()
    flag = data.draw(unknown_flags(parser))
    line = _refused(main, [flag], flag, capsys, workdir)
    assert "unrecognized arguments" in line


# -- --params files: refused by the nodes' own rules, naming the file, the line and the key -----
def _sim_graph_specs():
    return [(node, spec) for node in graph_params.graph_node_names("sim")
            for spec in graph_params.NODE_RULES[node][0]]


def _bad_values(spec) -> st.SearchStrategy:
    """Values the node refuses for `spec`: of another ROS type, or outside its range/choices."""
    default = spec.default
    if isinstance(default, list):
        kinds = {bool: st.booleans(), int: st.integers(-5, 5), float: st.floats(-5, 5),
                 str: words}
        own = type(default[0])
        wrong = st.one_of([s for k, s in kinds.items() if k is not own])
        bad = st.lists(wrong, min_size=1, max_size=3) | st.just([]) | kinds[own]
    else:
        kinds = {bool: st.booleans(), int: st.integers(-10**6, 10**6),
                 float: st.floats(allow_nan=False, allow_infinity=False), str: words}
        bad = st.one_of([s for k, s in kinds.items() if k is not type(default)])
        low, high = spec.low, spec.high
        if isinstance(default, int) and not isinstance(default, bool):
            if low is not None:
                bad |= st.integers(max_value=math.ceil(low) - 1)
            if high is not None:
                bad |= st.integers(min_value=math.floor(high) + 1)
        if isinstance(default, float):
            if low is not None:
                bad |= st.floats(max_value=low, allow_nan=False).filter(lambda v: v < low)
            if high is not None:
                bad |= st.floats(min_value=high, exclude_min=True)
            bad |= st.sampled_from([float("nan"), float("inf")])
        if spec.choices is not None:
            bad |= words.filter(lambda t: t not in spec.choices)
    return bad


@st.composite
def bad_params_files(draw):
    """(YAML text, what the refusal names): a section of no node, a key no node declares, or a
    value a node refuses; each key is on line 3."""
    kind = draw(st.sampled_from(["section", "key", "value"]))
    if kind == "section":
        node = draw(names.filter(lambda n: n not in graph_params.graph_node_names("sim")))
        return {node: {"ros__parameters": {"x": 1}}}, f"no node named '{node}'"
    if kind == "key":
        node = draw(st.sampled_from(graph_params.graph_node_names("sim")))
        known = {p.name for p in graph_params.NODE_RULES[node][0]} | TOLERATED_UNDECLARED
        name = draw(names.filter(lambda n: n not in known))
        return {node: {"ros__parameters": {name: 1}}}, f"unknown parameter '{name}'"
    node, spec = draw(st.sampled_from(_sim_graph_specs()))
    value = draw(_bad_values(spec))
    return {node: {"ros__parameters": {spec.name: value}}}, f"{node}: parameter '{spec.name}'"


@CHECKS
@given(case=bad_params_files())
@pytest.mark.parametrize("main", [demo.main, run.main], ids=["katana-demo", "katana-run"])
def test_a_bad_params_file_is_refused_with_its_line_and_key(workdir, capsys, main, case):
    doc, named = case
    path = workdir / "p.yaml"
    path.write_text(yaml.safe_dump(doc, default_flow_style=False))
    line = _refused(main, ["--params", str(path)], "--params", capsys, workdir)
    assert named in line, (doc, line)
    if "no node named" not in named:
        assert f"{path}:3:" in line, (doc, line)


# -- what a user found, pinned ------------------------------------------------------------------
PINNED = [
    ("curiosty_node:\n  ros__parameters:\n    theta: 0.5\n",
     "p.yaml:1: no node named 'curiosty_node' in the sim graph (did you mean 'curiosity_node'?)"),
    ("curiosity_node:\n  ros__parameters:\n    theta: [0.5\n", "p.yaml:4: not YAML"),
    (b"\x89PNG\r\n\x1a\n\x00\x00", "p.yaml:1: not a text file (byte 0x89 is not UTF-8)"),
    ("curiosity_node:\n  ros__parameters:\n    alhpa: 1.0\n",
     "p.yaml:3: unknown parameter 'alhpa' for node 'curiosity_node' (did you mean 'alpha'?)"),
    ("curiosity_node:\n  ros__parameters:\n    alpha: \"big\"\n",
     "p.yaml:3: curiosity_node: parameter 'alpha' is a string ('big'), expected a double"),
    ("curiosity_node:\n  ros__parameters:\n    theta: 5\n",
     "p.yaml:3: curiosity_node: parameter 'theta' is an integer (5), expected a double"),
    ("curiosity_node:\n  ros__parameters:\n    theta: 5.0\n",
     "p.yaml:3: curiosity_node: parameter 'theta' 5.0 is above 1; valid: in [0, 1]"),
    ("sim_node:\n  ros__parameters:\n    num_blocks: -3\n",
     "p.yaml:3: sim_node: parameter 'num_blocks' -3 is below 1; valid: in [1, 8]"),
    ("sim_node:\n  ros__parameters:\n    block_colors: [\"red\", \"green\"]\n",
     "p.yaml:3: sim_node: parameter 'block_colors': 2 colours for num_blocks 4"),
]


@pytest.mark.parametrize("text, named", PINNED)
def test_katana_demo_refuses_a_bad_params_file_before_its_run_folder(workdir, capsys, text,
                                                                      named):
    path = workdir / "p.yaml"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    line = _refused(demo.main, ["--out", "run", "--params", str(path)], "--params", capsys,
                    workdir)
    assert line.startswith("katana-demo: error: argument --params: ") and named in line, line
    assert not (workdir / "run").exists() and not (workdir / "runs").exists()


@pytest.mark.parametrize("argv, named", [
    (["--bogus-flag"], "unrecognized arguments: --bogus-flag"),
    (["--strategy", "bogus"], "argument --strategy: 'bogus' is not one of 'q1'"),
    (["--real-time-factor", "nan"], "argument --real-time-factor: nan is not finite"),
    (["--real-time-factor", "inf"], "argument --real-time-factor: inf is not finite"),
    (["--record", "/proc/x.mcap"], "argument --record: cannot write /proc/x.mcap"),
    (["--experiments", "0"], "argument --experiments: must be >= 1, got 0"),
    (["--seed", str(2**31)], "argument --seed: 2147483648 is above"),
    (["--ros-args", "-p"], "argument --ros-args: Failed to parse ROS arguments"),
    (["--ros-args", "-p", "curiosity_node:theta:=5.0"],
     "argument --ros-args: -p curiosity_node:theta:=5.0: curiosity_node: parameter 'theta'"),
    (["--ros-args", "-p", "bogus:=1"], "argument --ros-args: -p bogus:=1: unknown parameter"),
    (["--ros-args", "--", "--bogus"], "argument --ros-args: unrecognized arguments: --bogus"),
])
def test_katana_demo_refuses_at_parse_time_what_it_refused_late(workdir, capsys, argv, named):
    line = refused(demo.main, ["--out", "run", *argv], capsys)
    assert named in line, line
    assert tree(workdir) == BAD_WORKING_TREE


@CHECKS
@given(experiments=st.integers(1, 10_000_000), seed=st.integers(0, 2**31 - 1),
       strategy=st.sampled_from(sorted(STRATEGIES)), rtf=st.floats(0.0, 100.0),
       out=names)
def test_a_good_command_line_is_taken_as_given_and_creates_nothing_while_parsed(
        workdir, experiments, seed, strategy, rtf, out):
    before = tree(workdir)
    args, ros_args = demo.parse([f"--experiments={experiments}", f"--seed={seed}",
                                 f"--strategy={strategy}", f"--real-time-factor={rtf!r}",
                                 f"--out={out}", "--ros-args", "-p", "use_sim_time:=true"])
    assert (args.experiments, args.seed, args.strategy, args.real_time_factor) == \
        (experiments, seed, strategy, rtf)
    curiosity = args.param_set.values()["curiosity_node"]
    assert curiosity["run_dir"] == out and curiosity["max_experiments"] == experiments
    assert ros_args == ["--ros-args", "-p", "use_sim_time:=true"]
    assert tree(workdir) == before


@pytest.mark.parametrize("prog", [run, demo])
def test_the_command_lines_parameters_win_over_every_file(workdir, prog):
    """`--ros-args -p` beats the packaged files and every --params file (a node's own and a
    wildcard one), and reaches the node in its overrides (which rclpy ranks above the ROS
    arguments it parses itself); a dedicated option still beats -p."""
    path = workdir / "p.yaml"
    path.write_text("sim_node:\n  ros__parameters:\n    kinematic_free_space: true\n"
                    "curiosity_node:\n  ros__parameters:\n    theta: 0.3\n")
    packaged = run.load_params(run.default_params_files("sim"))
    assert packaged["sim_node"]["kinematic_free_space"] is True
    assert packaged["/**"]["use_sim_time"] is True
    argv = ["--params", str(path), "--ros-args", "-p", "sim_node:kinematic_free_space:=false",
            "-p", "curiosity_node:theta:=0.2", "-p", "use_sim_time:=false"]
    if prog is demo:
        args, _ = demo.parse(["--out", "run", "--seed", "7", *argv, "-p",
                              "curiosity_node:seed:=3"])
    else:
        args = parse_command_line(run.build_parser(), argv[:2],
                                  [run.graph_params_check(argv[2:])])
    values = args.param_set.values()
    assert values["sim_node"]["kinematic_free_space"] is False
    assert values["curiosity_node"]["theta"] == 0.2
    for node in ("sim_node", "curiosity_node", "fovea_node"):
        assert run.overrides_for(node, values)  # the node is given its parameters
        given = {p.name: p.value for p in run.overrides_for(node, values)}
        assert given["use_sim_time"] is False, node
    if prog is demo:
        assert values["curiosity_node"]["seed"] == 7  # --seed, not -p


def test_katana_run_checks_only_the_started_nodes_cross_rules(workdir, capsys):
    """A section of a layer not started is checked for names and values, not for the rules
    across the node's parameters (the node never starts)."""
    path = workdir / "p.yaml"
    path.write_text("curiosity_node:\n  ros__parameters:\n    table_action: 9\n")
    line = refused(run.main, ["--params", str(path)], capsys)
    assert "p.yaml:3: curiosity_node: parameter 'table_action' is 9" in line
    params = run.graph_param_set("sim", [path], layers=["arm"])
    assert params.values()["curiosity_node"]["table_action"] == 9


def _declaring(backend: str, name: str) -> dict[str, str]:
    """Started node -> the name it declares the shared parameter by."""
    started = graph_params.started_nodes(backend)
    return {n: own for n in started if (own := graph_params.shared_name(n, name))}


_OTHER_VALUE = {"model": "300_6m180", "camera_frame": "camera_color_optical_frame",
                "extrinsics_file": "calib.yaml", "world_frame": "table"}


@CHECKS
@given(data=st.data())
@pytest.mark.parametrize("backend", graph_params.BACKENDS)
@pytest.mark.parametrize("name", graph_params.SHARED_PARAMS)
def test_a_fact_of_the_whole_graph_given_two_values_is_refused(workdir, data, backend, name):
    """A node given another model, camera frame, extrinsics file or world frame than the rest
    is refused before any work, naming the parameter and the nodes on each side; the same
    value given to every node that declares it is taken."""
    nodes = _declaring(backend, name)
    assert len(nodes) >= 2, nodes  # else the rule would check nothing
    # the driver refuses every model but the 450: another node is the odd one there
    odd = data.draw(st.sampled_from(sorted(n for n in nodes if n != "katana_driver_node")),
                    label="odd node")
    value = _OTHER_VALUE[name]
    if name == "extrinsics_file":
        extrinsics = Calibration.overhead_default().extrinsics_yaml()
        (workdir / value).write_text(yaml.safe_dump(extrinsics))
    path = workdir / "p.yaml"
    path.write_text(yaml.safe_dump({odd: {"ros__parameters": {nodes[odd]: value}}}))
    params = graph_params.ParamSet().read(path)
    with pytest.raises(graph_params.ParamFileError) as refusal:
        graph_params.check_graph(params, backend, base=graph_params.hardware_base(backend))
    said = str(refusal.value)
    assert said.startswith(f"{path}:3: parameter '{name}' must be the same"), said
    assert all(n in said for n in nodes) and f"{value!r}" in said, said
    if backend == "hardware" and name == "model":
        return
    path.write_text(yaml.safe_dump({n: {"ros__parameters": {own: value}}
                                    for n, own in nodes.items()}))
    graph_params.check_graph(graph_params.ParamSet().read(path), backend,
                             base=graph_params.hardware_base(backend))


def test_katana_run_refuses_a_sim_of_another_model_than_the_executor_plans_for(workdir, capsys):
    path = workdir / "p.yaml"
    path.write_text("sim_node:\n  ros__parameters:\n    model: 400_6m180\n")
    line = _refused(run.main, ["--params", str(path)], "--params", capsys, workdir)
    assert "p.yaml:3: parameter 'model' must be the same" in line, line
    assert "sim_node: '400_6m180'" in line and "pick_place_executor" in line, line


# -- the installed console scripts ------------------------------------------------------------
@pytest.mark.parametrize("argv, named", [
    (["katana-demo", "--bogus-flag"], "unrecognized arguments: --bogus-flag"),
    (["katana-emulator", "--port", "99999"], "argument --port: must be in [0, 65535]"),
    (["katana-run", "--params", "p.yaml"], "argument --params: p.yaml:1: no node named"),
    (["katana-robot", "claims"], "the following arguments are required: RUN_DIR"),
    (["katana-robot", "paper", "--strategies", "bogus"], "argument --strategies"),
    (["katana-curiosity", "claims", "--resamples", "0"], "argument --resamples"),
    (["katana-play", "run.mcap"], "argument FILE.mcap: run.mcap does not exist"),
    (["katana-play", "p.yaml", "--rate", "0"], "argument --rate: must be > 0"),
])
def test_the_console_scripts_refuse_with_exit_2_and_no_traceback(tmp_path, argv, named):
    assert shutil.which(argv[0]), f"{argv[0]} is not installed (make setup, source scripts/env.sh)"
    (tmp_path / "p.yaml").write_text("curiosty_node:\n  ros__parameters: {}\n")
    proc = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, timeout=60,
                          env=dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="OFF"))
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    # nothing before the usage (pybullet prints its build time to stdout when imported)
    assert proc.stdout == ""
    lines = proc.stderr.splitlines()
    program = " ".join(argv[:2]) if argv[0] in ("katana-robot", "katana-curiosity") else argv[0]
    assert lines[0].startswith(f"usage: {program}"), proc.stderr
    assert [line for line in lines if ": error: " in line] == [lines[-1]]
    assert named in lines[-1], proc.stderr
    assert sorted(os.listdir(tmp_path)) == ["p.yaml"]
