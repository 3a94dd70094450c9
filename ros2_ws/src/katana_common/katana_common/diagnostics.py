"""/diagnostics for a node: its `Health` (katana_common.health) as diagnostic_msgs at 1 Hz of
wall time, as diagnostic_updater publishes it (status name "<node>: <component>")."""

from __future__ import annotations

from collections.abc import Callable, Mapping

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from .health import Health
from .qos import DIAGNOSTICS_QOS

DIAGNOSTICS_PERIOD_S = 1.0


def status_msg(name: str, hardware_id: str, health: Health) -> DiagnosticStatus:
    return DiagnosticStatus(
        level=bytes([health.level]), name=name, message=health.message,
        hardware_id=hardware_id,
        values=[KeyValue(key=str(k), value=_text(v)) for k, v in health.values.items()])


def _text(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.3g}"
    return str(value)


class Diagnostics:
    """Publishes each component's Health (a callable per component) once a second."""

    def __init__(self, node: Node, components: Mapping[str, Callable[[], Health]],
                 hardware_id: str = "") -> None:
        self.node = node
        self.components = dict(components)
        self.hardware_id = hardware_id
        self.publisher = node.create_publisher(DiagnosticArray, "/diagnostics", DIAGNOSTICS_QOS)
        self.timer = node.create_timer(DIAGNOSTICS_PERIOD_S, self.publish,
                                       clock=Clock(clock_type=ClockType.STEADY_TIME))

    def publish(self) -> None:
        msg = DiagnosticArray()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        name = self.node.get_name()
        for component, health in self.components.items():
            try:
                status = health()
            except Exception as exc:  # a broken report is itself news, never a dead node
                status = Health(3, f"no status: {exc!r}")
            msg.status.append(status_msg(f"{name}: {component}", self.hardware_id, status))
        self.publisher.publish(msg)
