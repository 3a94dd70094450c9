"""The layer rule's ban lists (ruff TID251, ros2_ws/src/ruff*.toml) cover what the repo has:
every ROS package imported anywhere and every node module are banned in core/, and every
core/ folder takes that rule. ruff fails on a banned import; this test fails on a gap."""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

SRC = Path(__file__).resolve().parents[2]  # ros2_ws/src
ROS_ROOTS = ("rclpy", "launch", "launch_ros")
ROS_SUFFIXES = ("_msgs", "_srvs", "_interfaces")
NODE_PACKAGES = ("katana_camera", "katana_curiosity", "katana_description", "katana_driver",
                 "katana_manipulation", "katana_perception", "katana_sim")



def _banned(config: str) -> set[str]:
    with open(SRC / config, "rb") as f:
        return set(tomllib.load(f)["lint"]["flake8-tidy-imports"]["banned-api"])


def _imports(path: Path) -> set[str]:
    """Absolute module names a file imports (relative imports resolved within its package)."""
    package = ".".join(path.relative_to(SRC).parts[1:-1])
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                names.add(".".join([*base, node.module] if node.module else base))
            else:
                names.add(node.module or "")
    return names


def _is_ros(name: str) -> bool:
    root = name.split(".")[0]
    return root in ROS_ROOTS or root.endswith(ROS_SUFFIXES)


def _covered(name: str, banned: set[str]) -> bool:
    parts = name.split(".")
    return any(".".join(parts[:i]) in banned for i in range(1, len(parts) + 1))


def _modules(package: str) -> list[Path]:
    return sorted((SRC / package / package).rglob("*.py"))


def test_every_ros_package_the_repo_imports_is_banned_in_core():
    banned = _banned("ruff-core.toml")
    used = {name.split(".")[0] for path in SRC.rglob("*.py") for name in _imports(path)
            if _is_ros(name)}
    assert used, "found no ROS import at all: the scan is broken"
    assert sorted(used - banned) == []


def test_every_node_module_is_banned_in_core():
    """A module outside core/ that uses ROS (directly or through katana_common) is a node
    module: core must not import it."""
    banned = _banned("ruff-core.toml")
    missing = []
    for package in NODE_PACKAGES:
        for path in _modules(package):
            if "core" in path.parts or path.name == "__init__.py":
                continue
            imports = _imports(path)
            if any(_is_ros(n) or n.startswith("katana_common") for n in imports):
                module = ".".join(path.relative_to(SRC).parts[1:]).removesuffix(".py")
                if not _covered(module, banned):
                    missing.append(module)
    assert missing == []


def test_every_core_folder_takes_the_core_rule():
    folders = sorted(p for p in SRC.glob("*/*/core") if p.is_dir())
    assert folders
    for folder in folders:
        with open(folder / "ruff.toml", "rb") as f:
            assert tomllib.load(f) == {"extend": "../../../ruff-core.toml"}, folder


def test_the_node_package_bans_are_in_every_layer_below_bringup():
    """ruff replaces the ban list on extend: the lower layers repeat the node packages' list."""
    node = _banned("ruff.toml")
    assert {"katana_bringup", "katana_paper", "matplotlib", "ray", "gymnasium"} <= node
    assert node <= _banned("ruff-core.toml")
    assert node <= _banned("ruff-base.toml")
