"""The viewers' files: the Foxglove layout names only topics the graph publishes (docs/DESIGN.md's
node graph table) and message paths that are fields of their types (rosidl's own field
introspection); the RViz file shows the arm, tf, the camera and the markers in "world"; the
launch files (read with ast: `launch` is not installed here) declare every argument they read,
and name files, executables and node names that exist."""

from __future__ import annotations

import ast
import importlib
import json
import re
from glob import glob
from pathlib import Path

import pytest
import yaml
from katana_bringup import foxglove_layout
from katana_bringup.foxglove_bridge import NAME as BRIDGE_NAME
from katana_bringup.live_view import EXTRA_TOPICS
from katana_bringup.recorder_node import TOPICS as RECORDED

SRC = Path(__file__).resolve().parents[2]  # ros2_ws/src
ROOT = SRC.parent.parent
LAYOUT = SRC / "katana_bringup" / "config" / foxglove_layout.FILE_NAME
RVIZ = SRC / "katana_description" / "rviz" / "katana.rviz"
LAUNCH_FILES = [SRC / "katana_bringup" / "launch" / "sim.launch.py",
                SRC / "katana_description" / "launch" / "display.launch.py"]
#: packages a full ROS 2 install brings (not on PyPI), which the launch files may start
FULL_INSTALL = {"robot_state_publisher": {"robot_state_publisher"},
                "tf2_ros": {"static_transform_publisher"},
                "joint_state_publisher_gui": {"joint_state_publisher_gui"},
                "rviz2": {"rviz2"}}
#: the types of the topics the layout may name
TOPIC_TYPES = {**{"/" + t[0]: t[2] for t in RECORDED},
               "/perception/debug_image": "sensor_msgs/msg/Image",
               "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
               "/robot_description": "std_msgs/msg/String"}
NUMERIC = {"bool", "boolean", "byte", "octet", "char", "float", "double", "int8", "uint8",
           "int16", "uint16", "int32", "uint32", "int64", "uint64", "float32", "float64"}


def graph_topics() -> set[str]:
    """Every topic the node graph table of docs/DESIGN.md says a node publishes."""
    text = (ROOT / "docs" / "DESIGN.md").read_text()
    table = text.split("## Node graph", 1)[1]
    topics = set()
    for line in table.splitlines():
        cells = line.split("|")
        if len(cells) < 4 or cells[1].strip() in ("node (package)", "---"):
            continue
        published = cells[2]
        while re.search(r"\([^()]*\)", published):  # notes in parentheses may hold commas
            published = re.sub(r"\([^()]*\)", "", published)
        for item in published.split(","):
            name = item.strip().split(" ")[0] if item.strip() else ""
            if re.fullmatch(r"/?[a-z_]+(/[a-z_]+)*", name):
                topics.add(name if name.startswith("/") else "/" + name)
    return topics


def test_the_design_table_is_read():
    topics = graph_topics()
    assert {"/camera/image_raw", "/curiosity/learner_state", "/diagnostics", "/fovea/markers",
            "/robot_description", "/tf", "/tf_static", "/perception/debug_image"} <= topics
    assert "/curiosity/experience" in topics and "-" not in topics


def test_the_packaged_layout_is_the_generated_one():
    assert LAYOUT.read_text() == foxglove_layout.render(), \
        "stale: run python -m katana_bringup.foxglove_layout --write"
    assert foxglove_layout.main([]) == 0


def _layout() -> dict:
    return json.loads(LAYOUT.read_text())


def _paths(layout: dict) -> list[str]:
    """Every topic or message path the panels name."""
    out = []
    for panel_id, cfg in layout["configById"].items():
        kind = panel_id.split("!")[0]
        if kind == "3D":
            out += list(cfg["topics"])
            out += [layer["topic"] for layer in cfg["layers"].values() if "topic" in layer]
        elif kind == "Image":
            out += [v for k, v in cfg["imageMode"].items() if k.endswith("Topic")]
        elif kind == "Plot":
            out += [p["value"] for p in cfg["paths"]] + [cfg["xAxisPath"]["value"]]
        elif kind == "RawMessages":
            out.append(cfg["topicPath"])
        elif kind == "DiagnosticSummary":
            out.append(cfg["topicToRender"])
        else:
            assert kind == "Tab", f"a panel this test does not read: {panel_id}"
    return out


def _topic(path: str) -> str:
    return next(t for t in sorted(TOPIC_TYPES, key=len, reverse=True)
                if path == t or path.startswith(t + "."))


def test_the_layout_has_the_panels_of_a_run():
    layout = _layout()
    kinds = [k.split("!")[0] for k in layout["configById"]]
    assert {"3D", "Image", "Plot", "RawMessages", "DiagnosticSummary", "Tab"} <= set(kinds)
    cfg = layout["configById"]
    assert cfg["3D!scene"]["followTf"] == "world"
    assert set(cfg["3D!scene"]["topics"]) == {"/memory/markers", "/fovea/markers",
                                              "/curiosity/markers"}
    images = {c["imageMode"]["imageTopic"] for k, c in cfg.items() if k.startswith("Image!")}
    assert images == {"/camera/image_raw", "/perception/debug_image"}
    assert cfg["RawMessages!experience"]["topicPath"] == "/curiosity/experience"
    assert cfg["DiagnosticSummary!diagnostics"]["topicToRender"] == "/diagnostics"
    # one plot per (height, field), one series per action, against the experiments made
    plots = {k: c for k, c in cfg.items() if k.startswith("Plot!")}
    heights = foxglove_layout._DEFAULTS["max_height"] + 1
    actions = foxglove_layout._DEFAULTS["n_actions"]
    assert len(plots) == 2 * heights
    for plot in plots.values():
        assert len(plot["paths"]) == actions
        assert plot["xAxisVal"] == "custom"
        assert plot["xAxisPath"]["value"] == "/curiosity/learner_state.experiments"
    assert plots["Plot!margin_h2"]["paths"][4]["value"] == \
        "/curiosity/learner_state.heights[:]{height==2}.margins[4]"
    # every panel is placed in the layout tree (directly or in a tab)
    placed = set(re.findall(r'"([A-Za-z0-9]+![a-z0-9_]+)"', json.dumps(
        [layout["layout"], [t["layout"] for t in cfg["Tab!learner"]["tabs"]]])))
    assert placed | {"Tab!learner"} == set(cfg) | {"Tab!learner"}


def test_every_topic_the_layout_names_is_published_by_the_graph_and_forwarded():
    topics = {_topic(p) for p in _paths(_layout())}
    assert topics <= graph_topics()
    forwarded = {"/" + t[0] for t in RECORDED} | {
        t if t.startswith("/") else "/" + t for t in EXTRA_TOPICS}
    assert topics <= forwarded


def _fields(type_name: str) -> dict[str, str]:
    """rosidl's field introspection of 'pkg/msg/Type' or 'pkg/Type'."""
    pkg, *_, name = type_name.split("/")
    cls = getattr(importlib.import_module(f"{pkg}.msg"), name)
    return cls.get_fields_and_field_types()


def _element(field_type: str) -> tuple[str, bool]:
    """(element type, is a sequence or array) of a rosidl field type."""
    m = re.fullmatch(r"sequence<([^,>]+)(?:, \d+)?>", field_type)
    if m:
        return m.group(1), True
    m = re.fullmatch(r"(.+)\[\d*\]", field_type)
    if m:
        return m.group(1), True
    return field_type, False


def check_path(path: str) -> str:
    """The type of the value a Foxglove message path names; AssertionError if any part of it
    is not a field (of the element type, after an index or a filter)."""
    topic = _topic(path)
    rest = path[len(topic):]
    current, is_list = TOPIC_TYPES[topic], False
    for token in re.findall(r"\.[a-z_0-9]+|\[[^\]]*\]|\{[^}]*\}", rest):
        if token.startswith("."):
            assert not is_list, f"{path}: {token} on a list"
            fields = _fields(current)
            assert token[1:] in fields, f"{path}: no field {token[1:]} in {current}"
            current, is_list = _element(fields[token[1:]])
        elif token.startswith("["):
            assert is_list, f"{path}: {token} on a field that is not a list"
            assert re.fullmatch(r"\[(\d+|:)\]", token), f"{path}: {token}"
            is_list = False  # an element, or with [:] each element (Foxglove's slice)
        else:  # a filter on the elements: {field==value}
            name = re.fullmatch(r"\{([a-z_0-9]+)==[^}]+\}", token).group(1)
            assert name in _fields(current), f"{path}: no field {name} to filter on"
    assert "".join(re.findall(r"\.[a-z_0-9]+|\[[^\]]*\]|\{[^}]*\}", rest)) == rest, path
    return current


def test_every_message_path_names_fields_of_its_type():
    plotted = [p for k, c in _layout()["configById"].items() if k.startswith("Plot!")
               for p in [*(x["value"] for x in c["paths"]), c["xAxisPath"]["value"]]]
    assert plotted
    for path in plotted:
        assert check_path(path) in NUMERIC, f"{path} is not a number"
    assert check_path("/curiosity/experience") == "katana_interfaces/msg/Experience"


@pytest.mark.parametrize("path", [
    "/curiosity/learner_state.heights[:]{height==0}.margin[0]",  # no such field
    "/curiosity/learner_state.heights.margins[0]",  # a field of a list without an index
    "/curiosity/learner_state.experiments[0]",  # an index on a number
    "/curiosity/learner_state.heights[:]{hight==0}.margins[0]",  # a filter on no field
])
def test_a_wrong_message_path_is_caught(path):
    with pytest.raises(AssertionError):
        check_path(path)


# -- RViz ------------------------------------------------------------------------------------
def test_the_rviz_view_shows_the_arm_tf_camera_and_markers_in_world():
    cfg = yaml.safe_load(RVIZ.read_text())["Visualization Manager"]
    assert cfg["Global Options"]["Fixed Frame"] == "world"
    displays = {}
    for d in cfg["Displays"]:
        topic = d.get("Description Topic", d.get("Topic", {})).get("Value")
        displays.setdefault(d["Class"].split("/")[-1], set()).add(topic)
    assert displays["RobotModel"] == {"/robot_description"}
    assert displays["TF"] == {None}
    assert displays["Image"] == {"/camera/image_raw"}
    assert displays["MarkerArray"] == {"/memory/markers", "/fovea/markers", "/curiosity/markers"}
    named = {t for ts in displays.values() for t in ts if t}
    assert named <= graph_topics()


# -- launch files ------------------------------------------------------------------------------
def _calls(tree: ast.AST, name: str) -> list[ast.Call]:
    return [n for n in ast.walk(tree) if isinstance(n, ast.Call)
            and getattr(n.func, "id", getattr(n.func, "attr", None)) == name]


def _kw(call: ast.Call, name: str):
    return next((k.value for k in call.keywords if k.arg == name), None)


def _console_scripts(package: str) -> set[str]:
    text = (SRC / package / "setup.py").read_text()
    return set(re.findall(r'"([\w-]+) = [\w.]+:\w+"', text))


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=lambda p: p.name)
def test_a_launch_file_declares_what_it_reads(path):
    tree = ast.parse(path.read_text())
    declared = {c.args[0].value for c in _calls(tree, "DeclareLaunchArgument")}
    read = {c.args[0].value for c in _calls(tree, "LaunchConfiguration")
            if isinstance(c.args[0], ast.Constant)}
    for helper in (f for f in ast.walk(tree) if isinstance(f, ast.FunctionDef)):
        params = [a.arg for a in helper.args.args]  # a helper reading the argument it is given
        for call in _calls(helper, "LaunchConfiguration"):
            if isinstance(call.args[0], ast.Name):
                i = params.index(call.args[0].id)
                read |= {c.args[i].value for c in _calls(tree, helper.name)}
    assert read == declared, f"read but not declared: {read - declared}; unused: {declared - read}"
    assert "generate_launch_description" in {f.name for f in tree.body
                                              if isinstance(f, ast.FunctionDef)}


def _installed(package: str, parts: list[str]) -> None:
    """The file (a pattern where the launch file formats a name) is in the source tree, and
    the package's setup.py installs its folder."""
    pattern = str(SRC / package / Path(*parts))
    assert glob(pattern), f"no {pattern}"
    setup = (SRC / package / "setup.py").read_text()
    assert f'"/{parts[0]}"' in setup and f'glob("{parts[0]}/' in setup, \
        f"{package}/setup.py does not install {parts[0]}/"


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=lambda p: p.name)
def test_a_launch_file_names_files_that_exist_and_are_installed(path):
    tree = ast.parse(path.read_text())
    joined = 0
    for call in _calls(tree, "join"):
        first = call.args[0]
        share = first if isinstance(first, ast.Call) else None
        if isinstance(first, ast.Name):  # share = get_package_share_directory("pkg")
            share = next(a.value for a in ast.walk(tree) if isinstance(a, ast.Assign)
                         and getattr(a.targets[0], "id", None) == first.id)
        if share is None or getattr(share.func, "id", None) != "get_package_share_directory":
            continue
        parts = []
        for arg in call.args[1:]:
            if isinstance(arg, ast.Constant):
                parts.append(arg.value)
            else:  # an f-string: its fields may be anything the arguments allow
                assert isinstance(arg, ast.JoinedStr)
                parts.append("".join(v.value if isinstance(v, ast.Constant) else "*"
                                     for v in arg.values))
        _installed(share.args[0].value, parts)
        joined += 1
    assert joined >= 1  # the RViz view (the URDF comes through katana_description.urdf_path)


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=lambda p: p.name)
def test_a_launch_file_starts_executables_that_exist(path):
    tree = ast.parse(path.read_text())
    nodes = _calls(tree, "Node")
    assert nodes
    for call in nodes:
        package, executable = _kw(call, "package"), _kw(call, "executable")
        if isinstance(package, ast.Constant) and isinstance(executable, ast.Constant):
            pairs = {(package.value, executable.value)}
        else:  # the loop over (package, executable) pairs in sim.launch.py
            pairs = {(e.elts[0].value, e.elts[1].value) for e in ast.walk(tree)
                     if isinstance(e, ast.Tuple) and len(e.elts) == 2
                     and all(isinstance(x, ast.Constant) for x in e.elts)
                     and str(e.elts[0].value).startswith("katana_")}
            assert pairs
        for pkg, exe in pairs:
            if pkg in FULL_INSTALL:
                assert exe in FULL_INSTALL[pkg], f"{pkg} has no {exe}"
            else:
                assert exe in _console_scripts(pkg), f"{pkg} has no console script {exe}"
        if pairs == {("katana_bringup", "foxglove_bridge")}:
            assert _kw(call, "name").value == BRIDGE_NAME


def test_sim_launch_offers_rviz_and_foxglove():
    tree = ast.parse(LAUNCH_FILES[0].read_text())
    args = {c.args[0].value: c for c in _calls(tree, "DeclareLaunchArgument")}
    for flag in ("rviz", "foxglove"):
        assert _kw(args[flag], "default_value").value == "false"
        assert [e.value for e in _kw(args[flag], "choices").elts] == ["true", "false"]
    assert {"foxglove_port", "foxglove_host", "frames"} <= set(args)
    assert "foxglove_bridge" in _console_scripts("katana_bringup")
