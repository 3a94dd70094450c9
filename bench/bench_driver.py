"""Driver speed against the katana-emulator on loopback (emulator latency off).

request_ms: median round trip of a position read (N 3 0) over TCP, framing and CRC included;
state_hz: joint_states messages per second that katana_driver_node delivers to a subscriber.
Targets: request_ms < 1 (the driver's own overhead) and state_hz >= 25. The real arm takes
about 40 ms a request; these numbers say nothing about it.
"""

from __future__ import annotations

import os
import statistics
import time

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")


def _request_times(client, n: int) -> list[float]:
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        client.read_positions()
        times.append((time.perf_counter() - t0) * 1e3)
    return times


def run() -> dict:
    import rclpy
    from katana_driver.core import protocol
    from katana_driver.core.client import KatanaClient
    from katana_driver.core.transport import SerialTransport, TcpTransport
    from katana_driver.emulator import KatanaEmulator, KatanaModel
    from katana_driver.katana_driver_node import KatanaDriverNode
    from rclpy.context import Context
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState

    emulator = KatanaEmulator(KatanaModel(calibrated=True))
    host, port = emulator.serve_tcp("127.0.0.1", 0)
    device = emulator.serve_pty()
    try:
        tcp = KatanaClient(TcpTransport(host, port, timeout=0.5))
        tcp.connect()
        _request_times(tcp, 50)  # warm-up
        tcp_ms = _request_times(tcp, 2000)
        tcp.close()
        serial = KatanaClient(SerialTransport(device, timeout=0.5))
        serial.connect()
        serial_ms = _request_times(serial, 300)
        serial.close()

        payload = protocol.read_positions().payload
        t0 = time.perf_counter()
        for _ in range(2000):
            protocol.frame_reply(emulator.model.handle(payload))
        emulator_ms = (time.perf_counter() - t0) / 2000 * 1e3

        ctx = Context()
        rclpy.init(context=ctx)
        node = KatanaDriverNode(
            node_name="bench_katana_driver",
            context=ctx,
            parameter_overrides=[Parameter("host", value=host), Parameter("port", value=port)],
        )
        probe = Node("bench_driver_probe", context=ctx)
        stamps: list[float] = []
        probe.create_subscription(
            JointState, "joint_states", lambda _: stamps.append(time.monotonic()), 50
        )
        executor = MultiThreadedExecutor(num_threads=4, context=ctx)
        executor.add_node(node)
        executor.add_node(probe)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and not (node.worker.ready and len(stamps) > 5):
            executor.spin_once(timeout_sec=0.05)
        stamps.clear()
        window_end = time.monotonic() + 4.0
        while time.monotonic() < window_end:
            executor.spin_once(timeout_sec=0.05)
        state_hz = (len(stamps) - 1) / (stamps[-1] - stamps[0]) if len(stamps) > 1 else 0.0
        executor.shutdown()
        node.destroy_node()
        probe.destroy_node()
        rclpy.shutdown(context=ctx)
    finally:
        emulator.stop()
    tcp_sorted = sorted(tcp_ms)
    return {
        "request_ms": round(statistics.median(tcp_ms), 4),
        "request_p95_ms": round(tcp_sorted[int(0.95 * len(tcp_sorted))], 4),
        "serial_request_ms": round(statistics.median(serial_ms), 4),
        "emulator_handle_ms": round(emulator_ms, 4),
        "state_hz": round(state_hz, 2),
        "poll_rate_hz": 25.0,
        "targets": {"request_ms": "< 1", "state_hz": ">= 25"},
        "note": "against the katana-emulator on loopback, latency off; not the real arm",
    }


if __name__ == "__main__":
    import json

    print(json.dumps(run(), indent=2))
