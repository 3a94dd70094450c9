"""run_recorder: the run's topics into one rosbag2 MCAP file (katana-run --record FILE.mcap).

Subscribes (serialized, never deserialized) to what shows a run: camera images and camera_info
(throttled to `image_rate_hz`), joint_states, /tf and /tf_static (the frame tree, so that a
player shows the arm, the image and the markers together), memory/blocks, perception/detections,
curiosity/experience, curiosity/learner_state and the block, fovea and curiosity markers. Each
message is stamped with its receive time on the node's clock (sim time with use_sim_time), as
`ros2 bag record` does. A topic's channel is made with its first message, carrying the QoS its
publishers offer (from the ROS graph, as rosbag2 records them), so that playback offers the
same (a transient-local topic stays transient local). Every `flush_period_s` of wall time the
open chunk is written out: a kill loses at most that much (katana-play --repair indexes what
is left).
"""

from __future__ import annotations

import sys

from katana_common.node_runner import run_node
from katana_common.params import Param, declare_parameters
from katana_common.qos import EVENT_QOS, JOINT_STATE_QOS, SENSOR_QOS, TF_QOS, TF_STATIC_QOS
from katana_interfaces.msg import BlockArray, Experience, LearnerState
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile
from sensor_msgs.msg import CameraInfo, Image, JointState
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

from . import bag_qos
from .recording import McapRecording

#: topic, message class, ROS type name, QoS, throttled with the images. State topics too are
#: taken as events (volatile, depth 100): every change is recorded, none squeezed out by the
#: depth of 1 that suits a late joiner; the recorder starts with the graph, before them. But
#: /tf_static is published once, when frame_publisher starts, which katana-run does before the
#: recorder: it is taken as a late joiner takes it (transient local), as `ros2 bag` does.
TOPICS = (
    ("camera/image_raw", Image, "sensor_msgs/msg/Image", SENSOR_QOS, True),
    ("camera/camera_info", CameraInfo, "sensor_msgs/msg/CameraInfo", SENSOR_QOS, True),
    ("joint_states", JointState, "sensor_msgs/msg/JointState", JOINT_STATE_QOS, False),
    ("/tf", TFMessage, "tf2_msgs/msg/TFMessage", TF_QOS, False),
    ("/tf_static", TFMessage, "tf2_msgs/msg/TFMessage", TF_STATIC_QOS, False),
    ("memory/blocks", BlockArray, "katana_interfaces/msg/BlockArray", EVENT_QOS, False),
    ("perception/detections", BlockArray, "katana_interfaces/msg/BlockArray", EVENT_QOS, False),
    ("curiosity/experience", Experience, "katana_interfaces/msg/Experience", EVENT_QOS, False),
    ("curiosity/learner_state", LearnerState, "katana_interfaces/msg/LearnerState", EVENT_QOS,
     False),
    ("memory/markers", MarkerArray, "visualization_msgs/msg/MarkerArray", EVENT_QOS, False),
    ("fovea/markers", MarkerArray, "visualization_msgs/msg/MarkerArray", EVENT_QOS, False),
    ("curiosity/markers", MarkerArray, "visualization_msgs/msg/MarkerArray", EVENT_QOS, False),
)

PARAMS = (
    Param("path", "run.mcap", "The MCAP file to write (read-only).", nonempty=True),
    Param("image_rate_hz", 2.0, "Images (and camera_info) recorded per second of the node's "
          "clock, at most; 0 records none (live).", 0.0, 100.0, live=True),
    Param("flush_period_s", 1.0, "Wall seconds between writes of the open chunk: the most a "
          "kill of the recorder loses (read-only).", 0.01, 60.0),
)


def offered_profile(qos: QoSProfile) -> dict:
    """A discovered publisher's QoS as bag_qos writes it (rmw's short policy names)."""
    return bag_qos.profile(
        history=qos.history.name.lower(), depth=qos.depth,
        reliability=qos.reliability.name.lower(), durability=qos.durability.name.lower(),
        deadline_ns=qos.deadline.nanoseconds, lifespan_ns=qos.lifespan.nanoseconds,
        liveliness=qos.liveliness.name.lower(),
        liveliness_lease_duration_ns=qos.liveliness_lease_duration.nanoseconds,
        avoid_ros_namespace_conventions=qos.avoid_ros_namespace_conventions)


class RecorderNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("run_recorder", **kwargs)
        self.params = declare_parameters(self, PARAMS)
        self.recording = McapRecording(self.params["path"])
        self._last_image_ns: dict[str, int] = {}
        for topic, cls, type_name, qos, throttled in TOPICS:
            self.create_subscription(
                cls, topic, self._callback(topic, type_name, throttled), qos, raw=True)
        self.create_timer(self.params["flush_period_s"], self.recording.flush,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _add_channel(self, topic: str, name: str, type_name: str) -> None:
        """The channel of `name`, with the QoS its publishers offer now (one just sent)."""
        infos = self.get_publishers_info_by_topic(name)
        self.recording.add_topic(name, type_name,
                                 offered_qos=[offered_profile(i.qos_profile) for i in infos])

    def _callback(self, topic: str, type_name: str, throttled: bool):
        name = self.resolve_topic_name(topic)

        def on_message(data: bytes) -> None:
            now_ns = self.get_clock().now().nanoseconds
            if throttled:
                rate = self.params["image_rate_hz"]
                last = self._last_image_ns.get(topic)
                if rate <= 0.0 or (last is not None and 0 <= now_ns - last < 1e9 / rate):
                    return
                self._last_image_ns[topic] = now_ns
            if not self.recording.has_topic(name):
                self._add_channel(topic, name, type_name)
            self.recording.write(name, data, now_ns)
        return on_message

    def stop(self) -> None:
        """Write the summary and close the file (run_node and katana-run call this)."""
        self.recording.close()

    def destroy_node(self) -> None:
        self.recording.close()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return run_node(RecorderNode, "run_recorder", args)


if __name__ == "__main__":
    sys.exit(main())
