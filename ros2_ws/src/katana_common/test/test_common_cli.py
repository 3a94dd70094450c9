"""The shared command-line validator (cli_args) and parameter-file checker (param_files): every
value is checked as its user will check it, nothing is created by a check, and a refusal names
the option, or the file, line and key."""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

import pytest
import rclpy
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from katana_common import cli_args
from katana_common.cli_args import (
    CommandLineError,
    float_in,
    from_spec,
    int_in,
    new_file,
    parse_command_line,
    readable_file,
    writable_folder,
)
from katana_common.cli_testing import refused, tree, words
from katana_common.node_runner import EXIT_INVALID_CONFIGURATION, run_node
from katana_common.param_files import ParamFileError, ParamSet, check_node, value_problem
from katana_common.param_spec import Param
from katana_common.params import ParameterError, declare_parameters
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")
FIXTURES = settings(suppress_health_check=[HealthCheck.function_scoped_fixture], deadline=None,
                    max_examples=40)

SPECS = (
    Param("alpha", 1.0, "a scale", low=1e-3, high=100.0),
    Param("count", 3, "a count", low=0, high=7),
    Param("strategy", "q1", "a choice", choices=("q1", "random")),
    Param("flag", False, "a flag"),
    Param("reach", [0.3, 0.2], "a list", low=0.0, high=1.0, min_length=1),
    Param("names", ["a"], "names"),
    Param("run_dir", "runs/x", "a folder", nonempty=True),
)


# -- numbers ------------------------------------------------------------------------------------
@given(st.integers(-10**30, 10**30) | words)
def test_whole_numbers_are_refused_outside_their_range_and_when_not_whole(value):
    check = int_in(0, 10)
    if isinstance(value, int) and 0 <= value <= 10:
        assert check(str(value)) == value
    else:
        with pytest.raises(argparse.ArgumentTypeError, match="must be in|expected a whole"):
            check(str(value))


@given(st.floats(allow_nan=True, allow_infinity=True) | words)
def test_numbers_must_be_finite_and_inside_the_interval(value):
    check = float_in(0.0, 1.0, high_open=True)
    if isinstance(value, float) and math.isfinite(value) and 0.0 <= value < 1.0:
        assert check(repr(value)) == value
    else:
        with pytest.raises(argparse.ArgumentTypeError, match=r"\[0, 1\)|expected"):
            check(repr(value) if isinstance(value, float) else value)


@given(st.sampled_from(SPECS[:3]), st.floats(allow_nan=True, allow_infinity=True)
       | st.integers(-1000, 1000) | words)
def test_an_option_that_sets_a_parameter_takes_exactly_what_the_spec_takes(spec, value):
    text = repr(value) if isinstance(value, float) else str(value)
    kind = type(spec.default)
    try:
        expected = kind(text) if kind in (int, float) else text
    except ValueError:
        expected = None
    check = from_spec(spec)
    if expected is not None and spec.problem(expected) is None:
        assert check(text) == expected
    else:
        with pytest.raises(argparse.ArgumentTypeError):
            check(text)


# -- files and folders: looked at, never made ----------------------------------------------------
_names = st.lists(st.from_regex(r"[a-z0-9._-]{1,12}", fullmatch=True).filter(
    lambda t: t not in (".", "..")), min_size=1, max_size=3)


@FIXTURES
@given(parts=_names)
def test_a_folder_to_write_is_probed_never_made(tmp_path, monkeypatch, parts):
    monkeypatch.chdir(tmp_path)
    before = tree(tmp_path)
    assert writable_folder(os.path.join(*parts)) == Path(*parts)
    assert tree(tmp_path) == before


@pytest.mark.parametrize("text, why", [
    ("", "expected a folder"),
    ("a\0b", "expected a folder"),
    ("file.txt", "is a file"),
    ("file.txt/sub/deeper", "inside a file"),
    ("/proc/no/such/folder", "cannot write in"),
    ("x" * 300, "name too long"),
])
def test_a_folder_that_cannot_be_written_is_refused_with_the_reason(tmp_path, monkeypatch, text,
                                                                     why):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "file.txt").write_text("x")
    before = tree(tmp_path)
    with pytest.raises(argparse.ArgumentTypeError, match=why):
        writable_folder(text)
    assert tree(tmp_path) == before


def test_a_file_to_write_and_a_file_to_read(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "old.mcap").write_bytes(b"x")
    mcap = new_file(".mcap")
    assert mcap("run.mcap") == Path("run.mcap") and mcap("old.mcap") == Path("old.mcap")
    for text, why in [("run.bag", "ending in .mcap"), (".mcap", "ending in .mcap"),
                      ("no/such/run.mcap", "no folder"), ("/proc/x.mcap", "cannot write"),
                      ("", "ending in")]:
        with pytest.raises(argparse.ArgumentTypeError, match=why):
            mcap(text)
    assert readable_file("old.mcap") == Path("old.mcap")
    for text, why in [("missing.yaml", "does not exist"), (".", "is a folder")]:
        with pytest.raises(argparse.ArgumentTypeError, match=why):
            readable_file(text)
    assert tree(tmp_path) == ["old.mcap"]


# -- the parse: a refusal names the option under the subcommand's usage ---------------------------
def _tool() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tool")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run")
    run.add_argument("--jobs", type=cli_args.positive_int, default=1)
    run.add_argument("--out", type=writable_folder, default="out")
    return parser


def _main(argv):
    def jobs_fit(args):
        if args.jobs > 4:
            raise CommandLineError("--jobs", f"{args.jobs} is more than the 4 slots")

    args = parse_command_line(_tool(), argv, [jobs_fit])
    args.out.mkdir()  # the work: only once every check passed
    return 0


@pytest.mark.parametrize("argv, line", [
    (["run", "--jobs", "9"], "tool run: error: argument --jobs: 9 is more than the 4 slots"),
    (["run", "--jobs", "0"], "tool run: error: argument --jobs: must be >= 1, got 0"),
    (["run", "--bogus"], "tool: error: unrecognized arguments: --bogus"),
    (["walk"], "tool: error: argument command: invalid choice: 'walk' (choose from 'run')"),
])
def test_a_refusal_is_the_usage_and_one_line_and_nothing_is_made(tmp_path, monkeypatch, capsys,
                                                                 argv, line):
    monkeypatch.chdir(tmp_path)
    assert refused(_main, argv, capsys) == line
    assert tree(tmp_path) == []
    assert _main(["run"]) == 0 and tree(tmp_path) == ["out"]


# -- parameter files: read with their lines, checked as the node checks ----------------------------
@pytest.mark.parametrize("text, where, why", [
    ("node:\n  ros__parameters:\n    alpha: [1.0,\n", ":4", "not YAML"),
    ("node:\n  ros__parameters:\n    alpha: 1.0\n  alpha: 2.0\n", ":4", "only ros__parameters"),
    ("node:\n  alpha: 1.0\n", ":2", "only ros__parameters"),
    ("node: 3\n", ":1", "no ros__parameters"),
    ("- node\n", ":1", "a mapping of node names"),
    ("node:\n  ros__parameters: [1]\n", ":2", "must be a mapping"),
    ("a: 1\n---\nb: 2\n", ":2", "not YAML"),
])
def test_a_file_that_is_not_parameter_yaml_is_named_with_its_line(tmp_path, text, where, why):
    path = tmp_path / "p.yaml"
    path.write_text(text)
    with pytest.raises(ParamFileError, match=why) as err:
        ParamSet().read(path)
    assert str(err.value).startswith(f"{path}{where}: ")


def test_a_binary_file_is_refused_without_a_traceback(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_bytes(b"node:\n\x89PNG\xff\x00")
    with pytest.raises(ParamFileError, match=rf"{path}:2: not a text file \(byte 0x89"):
        ParamSet().read(path)


def test_entries_keep_their_place_nested_names_are_dotted_and_later_files_win(tmp_path):
    a, b = tmp_path / "a.yaml", tmp_path / "b.yaml"
    a.write_text("/**:\n  ros__parameters:\n    flag: true\nnode:\n  ros__parameters:\n"
                 "    count: 1\n    sub:\n      alpha: 2.0\n")
    b.write_text("/node:\n  ros__parameters:\n    count: 9\n")
    params = ParamSet().read(a).read(b)
    assert params.values() == {"/**": {"flag": True}, "node": {"count": 9, "sub.alpha": 2.0}}
    assert params.sections["node"]["sub.alpha"].where == f"{a}:8"
    assert params.sections["node"]["count"].where == f"{b}:3"
    with pytest.raises(ParamFileError, match=rf"^{b}:3: node: parameter 'count' 9 is above 7"):
        check_node(params, "node", SPECS)
    params.set("node", "count", 2, "--count")
    with pytest.raises(ParamFileError, match=rf"^{a}:8: unknown parameter 'sub.alpha'"):
        check_node(params, "node", SPECS)


def test_a_cross_check_names_the_entry_of_the_parameter_it_names(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text("node:\n  ros__parameters:\n    count: 6\n    alpha: 5.0\n")
    params = ParamSet().read(path)

    def rule(values):
        return f"parameter 'alpha' {values['alpha']} exceeds count" \
            if values["alpha"] > values["count"] - 2 else None

    with pytest.raises(ParamFileError, match=rf"^{path}:4: node: parameter 'alpha' 5.0"):
        check_node(params, "node", SPECS, rule)


@pytest.fixture(scope="module")
def context():
    ctx = Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)


_scalars = (st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.text(max_size=6)
            | st.floats(allow_nan=True, allow_infinity=True))
_values = _scalars | st.lists(_scalars, max_size=3) | st.lists(
    st.floats(min_value=-2, max_value=2), max_size=3)


@settings(max_examples=150, deadline=None)
@given(spec=st.sampled_from(SPECS), value=_values)
def test_a_value_is_refused_before_start_up_exactly_when_the_node_refuses_it(context, spec,
                                                                                value):
    """The file check and the node agree: rclpy's type rule, 64-bit integers, then the spec."""
    try:
        node = Node("agree", context=context,
                    parameter_overrides=[Parameter(spec.name, value=value)])
    except (TypeError, ValueError):  # rclpy has no type for it: it stops the graph's build
        node = None
    if node is not None:
        try:
            declare_parameters(node, [spec])
            node_refuses = False
        except (ParameterError, SystemError):  # SystemError: an int beyond 64 bits, in rclpy
            node_refuses = True
        finally:
            node.destroy_node()
    else:
        node_refuses = True
    assert (value_problem(spec, value) is not None) == node_refuses, (spec.name, value)


# -- node executables: ROS arguments only, parsed before rclpy starts -----------------------------
@pytest.mark.parametrize("argv, why", [
    (["node", "--bogus"], "unrecognized arguments: --bogus"),
    (["node", "--ros-args", "-p"], "argument --ros-args: Failed to parse ROS arguments"),
    (["node", "--ros-args", "--no-such-flag"], "argument --ros-args:"),
    (["node", "--ros-args", "--params-file", "/no/such.yaml"], "argument --ros-args:"),
])
def test_a_node_executable_refuses_what_is_not_a_ros_argument(capsys, argv, why):
    def make_node():
        raise AssertionError("the node was started")

    assert run_node(make_node, "demo_node", argv) == EXIT_INVALID_CONFIGURATION
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0].startswith("usage: demo_node") and err[-1].startswith("demo_node: error: ")
    assert why in err[-1] and len(err) == 2
