"""Katana description: URDFs of the arm, table and blocks, and the arm facts they are built from."""

from __future__ import annotations

from pathlib import Path

PACKAGE = "katana_description"


def share_dir() -> Path:
    """The installed share folder (ament index), or the source tree when not installed."""
    try:
        from ament_index_python.packages import (  # noqa: PLC0415 - optional: ROS-free core
            get_package_share_directory,
        )

        return Path(get_package_share_directory(PACKAGE))
    except Exception:  # not installed, or ament_index_python absent: ROS-free core tests
        return Path(__file__).resolve().parent.parent


def urdf_path(name: str) -> Path:
    """Path of one of the package's URDF files, e.g. urdf_path('katana_450_6m180.urdf')."""
    path = share_dir() / "urdf" / name
    if not path.is_file():
        path = Path(__file__).resolve().parent.parent / "urdf" / name
    if not path.is_file():
        raise FileNotFoundError(f"{PACKAGE}: no URDF named {name}")
    return path
