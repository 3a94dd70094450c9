"""The Foxglove layout of a run (config/katana.foxglove-layout.json), written from here.

    python -m katana_bringup.foxglove_layout [--write]

One layout, imported once in the Foxglove app (Layouts, Import from file): a 3D view of the
markers in the world frame (where the fovea looks, the last placement and its label) and, where
robot_state_publisher runs, the arm from robot_description and /tf, the
camera image and perception's debug image, the learner's margin and confidence of every
(height, action) plotted against the experiments made (one plot per height, a tab each for
margins and confidences), the last experience record, and /diagnostics. The file is generated
so that it follows the learner's size (curiosity_node's max_height and n_actions); without
--write the command says whether the packaged file is current (exit 1 if not).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from katana_curiosity.node_params import PARAMS as CURIOSITY_PARAMS

from . import generated

FILE_NAME = "katana.foxglove-layout.json"
LEARNER = "/curiosity/learner_state"
FRAME = "world"
_DEFAULTS = {p.name: p.default for p in CURIOSITY_PARAMS}


def _plot(title: str, paths: list[tuple[str, str]]) -> dict[str, Any]:
    """A Plot panel of (message path, label) against the learner's experiment count."""
    return {
        "title": title,
        "paths": [{"value": value, "label": label, "enabled": True,
                   "timestampMethod": "receiveTime"} for value, label in paths],
        "xAxisVal": "custom",
        "xAxisPath": {"value": f"{LEARNER}.experiments", "enabled": True},
        "showLegend": True,
        "legendDisplay": "floating",
        "showXAxisLabels": True,
        "showYAxisLabels": True,
        "isSynced": False,
    }


def learner_path(height: int, field: str, action_index: int) -> str:
    """The message path of one (height, action)'s value: the HeightModel whose `height` field
    is `height` (not the array position), then the action's entry."""
    return f"{LEARNER}.heights[:]{{height=={height}}}.{field}[{action_index}]"


def build_layout(max_height: int = _DEFAULTS["max_height"],
                 n_actions: int = _DEFAULTS["n_actions"]) -> dict[str, Any]:
    heights = range(max_height + 1)
    config: dict[str, Any] = {
        "3D!scene": {
            "followTf": FRAME,
            "followMode": "follow-pose",
            "scene": {"transforms": {"showLabel": False}},
            "topics": {"/memory/markers": {"visible": True},
                       "/fovea/markers": {"visible": True},
                       "/curiosity/markers": {"visible": True}},
            "layers": {"grid": {"layerId": "foxglove.Grid", "visible": True,
                                "frameLocked": True, "size": 1, "divisions": 10,
                                "position": [0, 0, 0], "rotation": [0, 0, 0]},
                       # the arm: its model from robot_description, its links from /tf
                       # (frame_publisher, or robot_state_publisher on a full install)
                       "urdf": {"layerId": "foxglove.Urdf", "visible": True,
                                "sourceType": "topic", "topic": "/robot_description"}},
            "cameraState": {"perspective": True, "distance": 1.2, "phi": 50,
                            "thetaOffset": 45, "target": [0.22, 0, 0],
                            "targetOffset": [0, 0, 0], "targetOrientation": [0, 0, 0, 1],
                            "fovy": 45, "near": 0.01, "far": 100},
        },
        "Image!camera": {"imageMode": {"imageTopic": "/camera/image_raw",
                                       "calibrationTopic": "/camera/camera_info"}},
        "Image!debug": {"imageMode": {"imageTopic": "/perception/debug_image"}},
        "RawMessages!experience": {"topicPath": "/curiosity/experience", "diffEnabled": False,
                                   "diffMethod": "custom", "diffTopicPath": "",
                                   "showFullMessageForDiff": False, "expansion": "all"},
        "DiagnosticSummary!diagnostics": {"topicToRender": "/diagnostics", "pinnedIds": [],
                                          "hardwareIdFilter": "", "sortByLevel": True},
    }
    tabs = []
    for field, what in (("margins", "margin"), ("confidence", "confidence")):
        panels = []
        for h in heights:
            panel = f"Plot!{what}_h{h}"
            config[panel] = _plot(f"{what} at height {h} over experiments",
                                  [(learner_path(h, field, a), f"action {a + 1}")
                                   for a in range(n_actions)])
            panels.append(panel)
        tabs.append({"title": f"{what} per (height, action)", "layout": _stack(panels, "row")})
    config["Tab!learner"] = {"activeTabIdx": 0, "tabs": tabs}
    return {
        "configById": config,
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1},
        "layout": {
            "first": {"first": "3D!scene",
                      "second": {"first": "Image!camera", "second": "Image!debug",
                                 "direction": "row"},
                      "direction": "column", "splitPercentage": 55},
            "second": {"first": "Tab!learner",
                       "second": {"first": "RawMessages!experience",
                                  "second": "DiagnosticSummary!diagnostics",
                                  "direction": "row"},
                       "direction": "column", "splitPercentage": 60},
            "direction": "row",
            "splitPercentage": 50,
        },
    }


def _stack(panels: list[str], direction: str) -> str | dict[str, Any]:
    """Panels side by side, in equal shares (Foxglove's layout tree is binary)."""
    if len(panels) == 1:
        return panels[0]
    return {"first": panels[0], "second": _stack(panels[1:], direction),
            "direction": direction, "splitPercentage": 100.0 / len(panels)}


def render() -> str:
    return json.dumps(build_layout(), indent=2) + "\n"


def packaged_path() -> Path:
    """The layout in the source tree (config/, installed beside the YAML)."""
    return Path(__file__).resolve().parent.parent / "config" / FILE_NAME


def main(argv: list[str] | None = None) -> int:
    return generated.write_or_check("python -m katana_bringup.foxglove_layout",
                                    __doc__.split("\n\n")[0], {packaged_path(): render},
                                    "katana_bringup.foxglove_layout", argv)


if __name__ == "__main__":
    sys.exit(main())
