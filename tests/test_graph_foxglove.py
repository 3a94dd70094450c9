"""The simulated arm built by katana-run's build_nodes with --foxglove's bridge, watched by a
WebSocket client on loopback: the sim's topics are advertised with their ros2msg schemas, and
what arrives decodes, with nothing but those schemas (rosbags), to the sim's joints and
camera."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from katana_bringup.run import build_nodes, default_params_files, load_params
from katana_description.models import ALL_JOINTS
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "ros2_ws" / "src" / "katana_bringup"
                    / "test"))  # --import-mode=importlib
from foxglove_ws_client import FoxgloveClient, MessageFrame  # noqa: E402

WATCHED = ("/joint_states", "/camera/camera_info", "/camera/image_raw")


def _decode(channel: dict, payload: bytes):
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(channel["schema"], channel["schemaName"]))
    return store.deserialize_cdr(payload, channel["schemaName"])


def test_the_sim_is_watched_through_foxglove(ros_graph):
    g = ros_graph
    params = load_params(default_params_files("sim"))
    params["sim_node"].update(real_time_factor=0.0, seed=5)
    nodes = build_nodes("sim", params, g.context, layers=["arm"], foxglove=("127.0.0.1", 0))
    g.add(*nodes)
    bridge = next(n for n in nodes if n.get_name() == "foxglove_bridge")
    # connect once the channels exist (a channel made during the handshake may be refused)
    g.wait_for(lambda: set(WATCHED) <= set(bridge.view.channels.types()), timeout=60.0)
    with FoxgloveClient(bridge.view.port, timeout_s=30.0) as client:
        channels = client.wait_for_channels(set(WATCHED))
        subs = client.subscribe({t: channels[t] for t in WATCHED})
        received: dict[str, bytes] = {}
        deadline = time.monotonic() + 60.0
        while len(received) < len(WATCHED):
            assert time.monotonic() < deadline, f"only {sorted(received)} came through"
            event = client.next_event()  # within the socket's timeout
            if isinstance(event, MessageFrame):
                received.setdefault(subs[event.subscription], event.payload)

    joints = _decode(channels["/joint_states"], received["/joint_states"])
    assert set(joints.name) == set(ALL_JOINTS) and len(joints.position) == len(joints.name)
    info = _decode(channels["/camera/camera_info"], received["/camera/camera_info"])
    image = _decode(channels["/camera/image_raw"], received["/camera/image_raw"])
    assert (image.width, image.height) == (info.width, info.height) and image.width > 0
    assert image.encoding == "rgb8" and len(image.data) == image.step * image.height
    assert image.header.frame_id == info.header.frame_id == "camera_optical_frame"
