"""The stand-ins for standard interfaces (control_msgs, tf2_msgs) speak the real types.

A node talks to MoveIt or ros2_control only if the RIHS01 type hash of what it speaks equals
that of the installed upstream package. Here each built stand-in's hash (install/<pkg>/share/
<pkg>/<kind>/<Type>.json) is compared with

- the hash rosidl's own type-description machinery computes from upstream's field lists,
  written below as data (ROS 2 Jazzy: control_msgs 5.x, tf2_msgs of geometry2 jazzy), with the
  referenced standard types (std_msgs, trajectory_msgs, action_msgs, ...) taken from the Jazzy
  wheels in the venv, and
- the hash upstream's Jazzy build published (the RIHS01 constants in rosidl-generated code of
  an upstream control_msgs / tf2_msgs build).

Also: setup builds a stand-in only where no installed package provides it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from control_msgs.action import FollowJointTrajectory
from katana_description import arm_contract as ac
from rosidl_adapter.action import convert_action_to_idl
from rosidl_adapter.msg import convert_msg_to_idl
from rosidl_generator_type_description import generate_type_hash

ROOT = Path(__file__).resolve().parents[1]
INSTALL = ROOT / "install"
VENV_SHARE = Path(sys.prefix) / "share"

# Upstream's field lists (names, types, order: all that enters the hash; constants kept for
# the codes the graph relies on). control_msgs 5.x is the Jazzy release line; none of its
# releases changed these types.
UPSTREAM: dict[str, dict[str, str]] = {
    "control_msgs": {
        "msg/GripperCommand": """
float64 position
float64 max_effort
""",
        "msg/JointTolerance": """
string name
float64 position
float64 velocity
float64 acceleration
""",
        "msg/JointComponentTolerance": """
uint16 X_AXIS=1
uint16 Y_AXIS=2
uint16 Z_AXIS=3
uint16 TRANSLATION=4
uint16 ROTATION=5
string joint_name
uint16 component
float64 position
float64 velocity
float64 acceleration
""",
        "action/FollowJointTrajectory": """
trajectory_msgs/JointTrajectory trajectory
trajectory_msgs/MultiDOFJointTrajectory multi_dof_trajectory
JointTolerance[] path_tolerance
JointComponentTolerance[] component_path_tolerance
JointTolerance[] goal_tolerance
JointComponentTolerance[] component_goal_tolerance
builtin_interfaces/Duration goal_time_tolerance
---
int32 error_code
int32 SUCCESSFUL=0
int32 INVALID_GOAL=-1
int32 INVALID_JOINTS=-2
int32 OLD_HEADER_TIMESTAMP=-3
int32 PATH_TOLERANCE_VIOLATED=-4
int32 GOAL_TOLERANCE_VIOLATED=-5
string error_string
---
std_msgs/Header header
string[] joint_names
trajectory_msgs/JointTrajectoryPoint desired
trajectory_msgs/JointTrajectoryPoint actual
trajectory_msgs/JointTrajectoryPoint error
string[] multi_dof_joint_names
trajectory_msgs/MultiDOFJointTrajectoryPoint multi_dof_desired
trajectory_msgs/MultiDOFJointTrajectoryPoint multi_dof_actual
trajectory_msgs/MultiDOFJointTrajectoryPoint multi_dof_error
""",
        "action/GripperCommand": """
GripperCommand command
---
float64 position
float64 effort
bool stalled
bool reached_goal
---
float64 position
float64 effort
bool stalled
bool reached_goal
""",
    },
    "tf2_msgs": {
        "msg/TFMessage": """
geometry_msgs/TransformStamped[] transforms
""",
    },
}

# RIHS01 hashes found in rosidl-generated code of upstream builds (Jazzy's rosidl): the
# *__description.c / *__struct.h files a control_msgs or tf2_msgs build generates.
PUBLISHED = {
    "control_msgs/action/FollowJointTrajectory":
        "RIHS01_738ebcb7a2d7cfa42f9f1001cc99ce3a4383d1cfe508015d9be8485e4b1c66f6",
    "control_msgs/action/FollowJointTrajectory_Goal":
        "RIHS01_8a9060704b269608f5a340934cc26e66869dd14bdac29e2e7fd9ec8b9882d205",
    "control_msgs/action/FollowJointTrajectory_Result":
        "RIHS01_8002e99ed2c14c6faa522f2a93c26d744c5982f254f9e98ff9c6f19789bdb220",
    "control_msgs/action/FollowJointTrajectory_Feedback":
        "RIHS01_3fd0aaecf71725121ae1ff7f01098a5e0da581e672be18a6b2c286cb43d96b49",
    "control_msgs/action/GripperCommand":
        "RIHS01_e17c0e644eccf14bea84a0a93e0977182872c2eb7873ca6694900059b46dbc84",
    "control_msgs/msg/GripperCommand":
        "RIHS01_57eb8f326c9889ca8bb34ead82cc94cc09bf6bc5c3b6c09546dca3a00b589890",
    "control_msgs/msg/JointTolerance":
        "RIHS01_c254f9cece0f3b733017b6990fd46d1326e25242d6b8844398c97d9a88e7d648",
    "control_msgs/msg/JointComponentTolerance":
        "RIHS01_739ea7566931944d33830fa10f1bf5e7a7fbdc3172bce7a7eaac642bd6e3ffa4",
    "tf2_msgs/msg/TFMessage":
        "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
}

TYPES = [(pkg, name) for pkg, defs in UPSTREAM.items() for name in defs]


def _built_hashes(pkg: str, name: str) -> dict[str, str]:
    """Every hash in the stand-in's installed description (the type and what it references)."""
    path = INSTALL / pkg / "share" / pkg / f"{name}.json"
    assert path.is_file(), f"{path} missing: run scripts/setup.sh"
    data = json.loads(path.read_text())
    return {h["type_name"]: h["hash_string"] for h in data["type_hashes"]}


@pytest.fixture(scope="module")
def upstream_hashes(tmp_path_factory) -> dict[str, str]:
    """Hashes of UPSTREAM's definitions, computed the way rosidl's build computes them."""
    hashes: dict[str, str] = {}
    for pkg, defs in UPSTREAM.items():
        base = tmp_path_factory.mktemp(pkg)
        src, idl, out = base / "src", base / "idl", base / "out"
        tuples = []
        for name, text in defs.items():
            kind, type_name = name.split("/")
            rel = Path(kind) / f"{type_name}.{kind}"
            (src / kind).mkdir(parents=True, exist_ok=True)
            (idl / kind).mkdir(parents=True, exist_ok=True)
            (src / rel).write_text(text.lstrip())
            convert = convert_msg_to_idl if kind == "msg" else convert_action_to_idl
            convert(src, pkg, rel, idl / kind)
            tuples.append(f"{idl}:{kind}/{type_name}.idl")
        # referenced packages from the venv's Jazzy wheels, never from the workspace's install
        deps = [d.name for d in VENV_SHARE.iterdir() if d.name != pkg and (d / "msg").is_dir()]
        args = base / "args.json"
        args.write_text(json.dumps({
            "package_name": pkg,
            "output_dir": str(out),
            "idl_tuples": tuples,
            "include_paths": [f"{d}:{VENV_SHARE / d}" for d in deps],
        }))
        for path in generate_type_hash(str(args)):
            data = json.loads(Path(path).read_text())
            hashes.update({h["type_name"]: h["hash_string"] for h in data["type_hashes"]})
    return hashes


@pytest.mark.parametrize(("pkg", "name"), TYPES, ids=[f"{p}/{n}" for p, n in TYPES])
def test_built_hash_equals_upstream_definition(pkg, name, upstream_hashes):
    built = _built_hashes(pkg, name)
    full = f"{pkg}/{name}"
    assert built[full] == upstream_hashes[full]
    # the parts of an action (goal, result, feedback, its services) as well
    for type_name, value in built.items():
        assert value == upstream_hashes[type_name], type_name


@pytest.mark.parametrize("full", sorted(PUBLISHED))
def test_built_hash_equals_published_upstream_hash(full):
    pkg, kind, type_name = full.split("/")
    top = type_name.split("_")[0] if kind == "action" else type_name
    assert _built_hashes(pkg, f"{kind}/{top}")[full] == PUBLISHED[full]


def test_result_codes_are_upstream_constants():
    result = FollowJointTrajectory.Result
    for name in ("SUCCESSFUL", "INVALID_GOAL", "INVALID_JOINTS", "OLD_HEADER_TIMESTAMP",
                 "PATH_TOLERANCE_VIOLATED", "GOAL_TOLERANCE_VIOLATED"):
        assert getattr(result, name) == getattr(ac, name), name
    assert (result.SUCCESSFUL, result.INVALID_GOAL, result.GOAL_TOLERANCE_VIOLATED) == (0, -1, -5)


def _stand_ins(tmp_path: Path, prefixes: list[Path]) -> list[str]:
    env = {**os.environ, "AMENT_PREFIX_PATH": ":".join(map(str, prefixes)),
           "VIRTUAL_ENV": str(tmp_path / "empty-venv")}
    out = subprocess.run(["bash", str(ROOT / "scripts" / "installed_stand_ins.sh"), str(ROOT)],
                         env=env, capture_output=True, text=True, check=True, timeout=60)
    return out.stdout.split()


def _prefix(root: Path, pkg: str, package_xml: str) -> Path:
    (root / "share" / "ament_index" / "resource_index" / "packages").mkdir(parents=True)
    (root / "share" / "ament_index" / "resource_index" / "packages" / pkg).touch()
    (root / "share" / pkg).mkdir(parents=True)
    (root / "share" / pkg / "package.xml").write_text(package_xml)
    return root


def test_an_installed_package_replaces_its_stand_in(tmp_path):
    opt = _prefix(tmp_path / "opt", "control_msgs", "<package><name>control_msgs</name></package>")
    assert _stand_ins(tmp_path, []) == []
    assert _stand_ins(tmp_path, [opt]) == ["control_msgs"]


def test_a_built_stand_in_is_not_an_installed_package(tmp_path):
    """The workspace's own install (sourced by env.sh) must not make setup skip the build."""
    own = (INSTALL / "control_msgs" / "share" / "control_msgs" / "package.xml").read_text()
    overlay = _prefix(tmp_path / "install" / "control_msgs", "control_msgs", own)
    assert _stand_ins(tmp_path, [overlay]) == []
    assert _stand_ins(tmp_path, [INSTALL / "control_msgs", INSTALL / "tf2_msgs"]) == []
