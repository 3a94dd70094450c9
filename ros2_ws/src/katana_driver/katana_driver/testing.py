"""Fault cases of the driver against the EMULATOR, shared by the tests and bench/bench_driver.py
(test support: no node or launch file imports it).

Each case runs katana_driver_node in-process (own Context) against a KatanaEmulator, sends one
trajectory goal, turns one fault knob on (from the start, or mid-trajectory), and records what
the emulated controller saw: segments it got twice (``duplicated_segments``), the largest
per-10 ms joint step as a fraction of the joint's speed limit (``max_speed_ratio``), how the
goal ended (``outcome``), and whether the node then served the next goal (the fault cleared).
"""

from __future__ import annotations

import functools
import itertools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import rclpy
from control_msgs.action import FollowJointTrajectory
from katana_common.action_client import ActionClient
from katana_common.executor import MultiThreadedExecutor
from katana_common.messages import duration_msg
from katana_common.testing import spin_until
from katana_emulator.emulator import Faults, KatanaEmulator, KatanaModel
from rclpy.action.client import GoalStatus
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectoryPoint

from katana_driver.core.encoders import ARM_JOINTS, EncoderModel
from katana_driver.core.protocol import KNI_MAX_ACCELERATION, TICK_S
from katana_driver.katana_driver_node import KatanaDriverNode

_ids = itertools.count()
#: two poses 0.5-1.3 rad apart on every arm joint; 2 s from one to the other (at rest at both)
#: takes the wrist roll to 0.9 of its acceleration limit and 0.44 of its speed limit: a segment
#: played twice or out of turn jumps back a whole segment, a speed ratio far above 1
POSE_A = [-1.2, 1.3, -1.2, -0.6, -1.0]
POSE_B = [-2.4, 1.8, -1.8, -1.4, -2.3]
LEG_S = 2.0
_MODEL = EncoderModel()


def seconds_between(a: list[float], b: list[float], accel_fraction: float = 0.8) -> float:
    """A duration for a rest-to-rest move from pose ``a`` to ``b`` that keeps every joint
    within ``accel_fraction`` of KNI's acceleration limit and 80 % of its speed limit (a cubic
    from rest to rest peaks at 6 d / T^2 and 1.5 d / T)."""
    ticks = 100.0
    for j in range(5):
        d = abs(_MODEL.angle_to_encoder(j + 1, a[j]) - _MODEL.angle_to_encoder(j + 1, b[j]))
        ticks = max(ticks, math.sqrt(6.0 * d / (KNI_MAX_ACCELERATION * accel_fraction)),
                    1.5 * d / (0.8 * _MODEL.speed_limit_enc(j + 1)))
    return math.ceil(ticks) * TICK_S


def _knobs(**kw) -> Callable[[KatanaEmulator], None]:
    def apply(emulator: KatanaEmulator) -> None:
        for key, value in kw.items():
            setattr(emulator.faults, key, value)

    return apply


def _for(attribute: str, seconds: float) -> Callable[[KatanaEmulator], None]:
    def apply(emulator: KatanaEmulator) -> None:
        setattr(emulator.faults, attribute, time.monotonic() + seconds)

    return apply


def _drop_tcp(emulator: KatanaEmulator) -> None:
    emulator.drop_connection()


#: name -> (apply the fault, apply it mid-trajectory (True) or before the goal (False))
FAULTS: dict[str, tuple[Callable[[KatanaEmulator], None], bool]] = {
    "drop_5pct": (_knobs(silent_rate=0.05), False),
    "drop_20pct": (_knobs(silent_rate=0.20), False),
    "crc_5pct": (_knobs(corrupt_rate=0.05), False),
    "crc_20pct": (_knobs(corrupt_rate=0.20), False),
    "split_replies": (_knobs(split_replies=True), False),
    "latency_40ms": (_knobs(latency_s=0.04), False),
    "spline_replies_0.6s_late": (_knobs(spline_latency_s=0.6), False),
    "silent_3s_mid_trajectory": (_for("silent_until", 3.0), True),
    "silent_for_good": (_for("silent_until", math.inf), True),
    "tcp_drop": (_drop_tcp, True),
    "controller_frozen_4s": (_for("frozen_until", 4.0), True),
    "emulator_restart": (None, True),  # handled by FaultBench: a new emulator, same port
}


@dataclass
class CaseResult:
    duplicated_segments: int
    max_speed_ratio: float
    outcome: str
    next_goal: str

    def as_dict(self) -> dict:
        return {
            "duplicated_segments": self.duplicated_segments,
            "max_speed_ratio": round(self.max_speed_ratio, 4),
            "outcome": self.outcome,
            "next_goal": self.next_goal,
        }


def trajectory(q: list[float], seconds: float) -> FollowJointTrajectory.Goal:
    return waypoints([(seconds, q)])


def waypoints(points: list[tuple[float, list[float]]]) -> FollowJointTrajectory.Goal:
    goal = FollowJointTrajectory.Goal()
    goal.trajectory.joint_names = list(ARM_JOINTS)
    goal.trajectory.points = [
        JointTrajectoryPoint(positions=list(q), time_from_start=duration_msg(t)) for t, q in points
    ]
    return goal


def back_and_forth(legs: int, leg_s: float = LEG_S) -> FollowJointTrajectory.Goal:
    """From POSE_A: B, A, B, ... one leg each ``leg_s``, stopping at every pose."""
    return waypoints([((k + 1) * leg_s, POSE_B if k % 2 == 0 else POSE_A) for k in range(legs)])


class FaultBench:
    """One emulator, one driver node, one client node; ``close()`` stops them."""

    def __init__(self, timeout_s: float = 0.2, retries: int = 3, **driver_params) -> None:
        self.emulator = KatanaEmulator(KatanaModel(calibrated=True), Faults(seed=1))
        self.host, self.port = self.emulator.serve_tcp("127.0.0.1", 0)
        self.old_emulators: list[KatanaEmulator] = []
        self.ctx = Context()
        rclpy.init(context=self.ctx)
        n = next(_ids)
        params = {
            "host": self.host,
            "port": self.port,
            "timeout": timeout_s,
            "retries": retries,
            "reconnect_period": 0.2,
            **driver_params,
        }
        self.driver = KatanaDriverNode(
            node_name=f"katana_driver_faults_{n}",
            context=self.ctx,
            parameter_overrides=[Parameter(k, value=v) for k, v in params.items()],
        )
        self.client = Node(f"katana_driver_faults_client_{n}", context=self.ctx)
        self.states: list[float] = []
        self.client.create_subscription(
            JointState, "joint_states", lambda _m: self.states.append(time.monotonic()), 50
        )
        self.arm = ActionClient(
            self.client, FollowJointTrajectory, "arm_controller/follow_joint_trajectory"
        )
        self.executor = MultiThreadedExecutor(num_threads=4, context=self.ctx)
        self.executor.add_node(self.driver)
        self.executor.add_node(self.client)
        self.spin_until = functools.partial(spin_until, self.executor)

    def wait_ready(self, limit_s: float = 15.0) -> bool:
        return self.spin_until(
            lambda: self.driver.ready and self.arm.server_is_ready(), limit_s
        )

    def run_goal(
        self,
        goal,
        limit_s: float = 40.0,
        during: Callable[[], None] | None = None,
        at_s: float = 0.0,
    ) -> tuple[int, str]:
        """(GoalStatus, error_string); ``during`` runs ``at_s`` after the goal was accepted."""
        sent = self.arm.send_goal_async(goal)
        if not self.spin_until(sent.done, 10.0) or not sent.result().accepted:
            return GoalStatus.STATUS_UNKNOWN, "not accepted"
        result = sent.result().get_result_async()
        if during is not None:
            self.spin_until(result.done, at_s)
            during()
        if not self.spin_until(result.done, limit_s):
            return GoalStatus.STATUS_UNKNOWN, f"no result within {limit_s} s (hung)"
        res = result.result()
        return res.status, res.result.error_string

    def restart_emulator(self) -> None:
        """The controller process restarts on the same port (a fresh, calibrated model)."""
        old = self.emulator
        old.stop()
        self.old_emulators.append(old)
        self.emulator = KatanaEmulator(KatanaModel(calibrated=True), Faults(seed=2))
        self.emulator.serve_tcp(self.host, self.port)

    def counters(self) -> tuple[int, float]:
        models = [e.model for e in (*self.old_emulators, self.emulator)]
        return (sum(m.duplicated_segments for m in models), max(m.max_speed_ratio for m in models))

    def run_case(self, name: str, legs: int = 3) -> CaseResult:
        apply, mid = FAULTS[name]
        if not self.wait_ready():
            return CaseResult(0, 0.0, "driver not ready", "")
        state = self.driver.worker.state
        here = list(state.positions[:5]) if state is not None else POSE_B
        status, text = self.run_goal(trajectory(POSE_A, seconds_between(here, POSE_A)))
        self.emulator.model.reset_counters()
        self.emulator.faults = Faults(seed=3)
        if name == "emulator_restart":
            during = self.restart_emulator
        else:

            def during() -> None:
                apply(self.emulator)

            if not mid:
                during()
        seconds = legs * LEG_S
        status, text = self.run_goal(
            back_and_forth(legs), during=during if mid else None, at_s=seconds / 2
        )
        outcome = "succeeded" if status == GoalStatus.STATUS_SUCCEEDED else f"aborted: {text}"
        dup, ratio = self.counters()
        self.emulator.faults = Faults(seed=4)  # the fault clears; the node must serve again
        self.wait_ready(15.0)
        state = self.driver.worker.state
        back = [q for q in state.positions[:5]] if state is not None else POSE_A
        to_a = max(abs(a - b) for a, b in zip(back, POSE_A, strict=True))
        to_b = max(abs(a - b) for a, b in zip(back, POSE_B, strict=True))
        target = POSE_A if to_a > to_b else POSE_B  # a goal that moves
        status, text = self.run_goal(trajectory(target, seconds_between(back, target)))
        next_goal = "succeeded" if status == GoalStatus.STATUS_SUCCEEDED else f"failed: {text}"
        dup2, ratio2 = self.counters()
        return CaseResult(max(dup, dup2), max(ratio, ratio2), outcome, next_goal)

    def close(self) -> None:
        self.arm.destroy()
        self.executor.shutdown()
        self.driver.destroy_node()
        self.client.destroy_node()
        rclpy.shutdown(context=self.ctx)
        self.emulator.stop()
