"""The QoS profiles of the graph, one per purpose (import these; define no others)."""

from __future__ import annotations

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

#: latest state for late joiners (memory/blocks, learner_state, ground truth, markers)
STATE_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
    reliability=ReliabilityPolicy.RELIABLE,
)

#: camera images and camera_info: newest frame wins, losses are fine (REP 2003)
SENSOR_QOS = qos_profile_sensor_data

#: joint_states, as robot_state_publisher and ros2_control publish and expect them
JOINT_STATE_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    durability=DurabilityPolicy.VOLATILE,
    reliability=ReliabilityPolicy.RELIABLE,
)

#: events every subscriber must see once each (curiosity/experience, detections)
EVENT_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
    durability=DurabilityPolicy.VOLATILE,
    reliability=ReliabilityPolicy.RELIABLE,
)

#: /clock, as rclpy's TimeSource subscribes to it (best effort, depth 1) can receive it
CLOCK_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    durability=DurabilityPolicy.VOLATILE,
    reliability=ReliabilityPolicy.BEST_EFFORT,
)

#: /diagnostics (diagnostic_msgs/DiagnosticArray), as diagnostic_updater publishes it and the
#: aggregator and Foxglove subscribe (reliable, volatile)
DIAGNOSTICS_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    durability=DurabilityPolicy.VOLATILE,
    reliability=ReliabilityPolicy.RELIABLE,
)

#: /tf, as tf2_ros's TransformBroadcaster publishes it (tf2_ros DynamicBroadcasterQoS and the
#: Python TransformBroadcaster: reliable, volatile, depth 100) and robot_state_publisher uses
TF_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
    durability=DurabilityPolicy.VOLATILE,
    reliability=ReliabilityPolicy.RELIABLE,
)

#: /tf_static, as tf2_ros's StaticTransformBroadcaster publishes it (StaticBroadcasterQoS:
#: reliable, transient local, depth 1): one message holds every static transform of the
#: publisher, and a late listener still gets it
TF_STATIC_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
    reliability=ReliabilityPolicy.RELIABLE,
)

#: /robot_description (std_msgs/String, the URDF), as robot_state_publisher publishes it
#: (rclcpp::QoS(1).transient_local(): reliable) and RViz and Foxglove subscribe
ROBOT_DESCRIPTION_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
    reliability=ReliabilityPolicy.RELIABLE,
)
