"""sim_node: the PyBullet Katana world on ROS 2 (thin: the world lives in katana_sim.core).

Publishes camera/image_raw + camera/camera_info (sensor-data QoS), joint_states, /clock and
sim/ground_truth (transient local; for tests and evaluation only: nothing that learns may read
it). Serves arm_controller/follow_joint_trajectory, gripper_controller/gripper_command and
~/reset_world.

Physics runs in one stepping thread. With real_time_factor > 0 it keeps simulated time at that
multiple of wall-clock time; with 0 it runs as fast as it can while the arm or gripper moves and
at wall-clock pace when idle (so released blocks still settle). Action callbacks only start a
motion and wait, with a bounded wait, for the stepping thread to finish it, so the node needs a
MultiThreadedExecutor (its main() makes one).
"""

from __future__ import annotations

import math
import sys
import threading
import time

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Pose
from katana_description import models as m
from katana_interfaces.action import FollowJointTrajectory, GripperCommand
from katana_interfaces.msg import Block, BlockArray
from katana_interfaces.srv import ResetWorld
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, qos_profile_sensor_data
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, JointState
from trajectory_msgs.msg import JointTrajectoryPoint

from katana_sim.core import CameraModel, ConfigError, SimConfig, SimWorld, TrajectoryGoal
from katana_sim.core import controllers as ctl


def _stamp(t: float) -> Time:
    sec = int(math.floor(t))
    return Time(sec=sec, nanosec=int((t - sec) * 1e9))


def _duration(d) -> float:
    return float(d.sec) + float(d.nanosec) * 1e-9


def _frange(lo: float, hi: float) -> list[FloatingPointRange]:
    return [FloatingPointRange(from_value=lo, to_value=hi, step=0.0)]


class SimNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("sim_node", **kwargs)
        self._declare()
        g = self.get_parameter
        cfg = SimConfig(
            model=g("model").value,
            num_blocks=g("num_blocks").value,
            block_colors=tuple(g("block_colors").value),
            block_size=tuple(g("block_size").value),
            block_mass=g("block_mass").value,
            seed=g("seed").value,
            physics_rate=g("physics_rate").value,
            camera=CameraModel(
                width=g("image_width").value,
                height=g("image_height").value,
                focal_px=g("camera_focal_px").value,
                position=tuple(g("camera_position").value),
                rpy=tuple(g("camera_rpy").value),
                frame_id=g("camera_frame").value,
            ),
            play_x=tuple(g("play_x").value),
            play_y=tuple(g("play_y").value),
            play_radius=tuple(g("play_radius").value),
        )
        for name in ("play_x", "play_y", "play_radius"):
            if len(getattr(cfg, name)) != 2:
                raise ConfigError(name, "two numbers (min, max)")
        cfg.validate()  # raises ConfigError naming the parameter
        self.rtf = float(g("real_time_factor").value)
        self.camera_rate = float(g("camera_rate").value)
        self.joint_state_rate = float(g("joint_state_rate").value)
        self.ground_truth_rate = float(g("ground_truth_rate").value)
        self.clock_rate = float(g("clock_rate").value)
        self.publish_clock = bool(g("publish_clock").value)
        self.world_frame = g("world_frame").value

        self.world = SimWorld(cfg)
        self.lock = threading.RLock()
        self._stepped = threading.Condition()
        group = ReentrantCallbackGroup()
        state_qos = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.image_pub = self.create_publisher(Image, "camera/image_raw", qos_profile_sensor_data)
        self.info_pub = self.create_publisher(CameraInfo, "camera/camera_info",
                                              qos_profile_sensor_data)
        self.joint_pub = self.create_publisher(JointState, "joint_states", 10)
        self.truth_pub = self.create_publisher(BlockArray, "sim/ground_truth", state_qos)
        self.clock_pub = self.create_publisher(Clock, "/clock", 10) if self.publish_clock else None
        self.arm_server = ActionServer(
            self, FollowJointTrajectory, "arm_controller/follow_joint_trajectory",
            execute_callback=self._execute_trajectory, goal_callback=self._accept,
            cancel_callback=self._cancel, callback_group=group)
        self.gripper_server = ActionServer(
            self, GripperCommand, "gripper_controller/gripper_command",
            execute_callback=self._execute_gripper, goal_callback=self._accept,
            cancel_callback=self._cancel, callback_group=group)
        self.reset_srv = self.create_service(ResetWorld, "~/reset_world", self._reset,
                                             callback_group=group)
        self._next = {"joints": 0.0, "camera": 0.0, "truth": 0.0, "clock": 0.0,
                      "clock_wall": 0.0, "joints_wall": 0.0}
        self._last_render_wall = 0.0
        self._running = True
        self._thread = threading.Thread(target=self._loop, name="sim_stepper", daemon=True)
        self._thread.start()
        self.get_logger().info(
            f"sim ready: {cfg.num_blocks} blocks, physics {cfg.physics_rate:g} Hz, "
            f"real_time_factor {self.rtf:g}, camera {cfg.camera.width}x{cfg.camera.height}")

    # ------------------------------------------------------------------ parameters
    def _declare(self) -> None:
        def d(name, value, text, **ranges):
            self.declare_parameter(name, value, ParameterDescriptor(description=text, **ranges))

        d("model", m.DEFAULT_MODEL, f"Katana type: one of {sorted(m.MODELS)}")
        d("num_blocks", 4, "number of blocks (1..8)",
          integer_range=[IntegerRange(from_value=1, to_value=8, step=1)])
        d("block_colors", list(m.DEFAULT_COLOURS),
          f"block colours, distinct, the first num_blocks are used; known: {list(m.COLOURS)}")
        d("block_size", list(m.BLOCK_SIZE), "block edges x, y, z (m), each 0.01..0.08")
        d("block_mass", m.BLOCK_MASS, "block mass (kg)", floating_point_range=_frange(0.001, 0.4))
        d("seed", 0, "seed of the first scatter and of the reset sequence",
          integer_range=[IntegerRange(from_value=0, to_value=2**31 - 1, step=1)])
        d("physics_rate", 240.0, "physics steps per simulated second (Hz)",
          floating_point_range=_frange(60.0, 5000.0))
        d("real_time_factor", 1.0,
          "simulated seconds per wall second; 0 = as fast as possible while the arm moves",
          floating_point_range=_frange(0.0, 100.0))
        d("camera_position", [0.22, 0.0, 0.75], "camera_optical_frame origin in world (m)")
        d("camera_rpy", [math.pi, 0.0, -math.pi / 2],
          "camera_optical_frame orientation in world, roll pitch yaw (rad)")
        d("camera_focal_px", 750.0, "focal length fx = fy (px)",
          floating_point_range=_frange(10.0, 10000.0))
        d("image_width", 640, "image width (px)",
          integer_range=[IntegerRange(from_value=16, to_value=4096, step=1)])
        d("image_height", 480, "image height (px)",
          integer_range=[IntegerRange(from_value=16, to_value=4096, step=1)])
        d("camera_rate", 10.0, "images per second (sim and wall time); 0 = no images",
          floating_point_range=_frange(0.0, 60.0))
        d("joint_state_rate", 25.0, "joint_states per simulated second",
          floating_point_range=_frange(1.0, 1000.0))
        d("ground_truth_rate", 2.0, "sim/ground_truth per simulated second",
          floating_point_range=_frange(0.1, 100.0))
        d("publish_clock", True, "publish /clock (for nodes with use_sim_time)")
        d("clock_rate", 100.0, "/clock messages per simulated second",
          floating_point_range=_frange(1.0, 1000.0))
        d("world_frame", "world", "frame of block poses")
        d("camera_frame", "camera_optical_frame", "frame_id of the images")
        d("play_x", [0.14, 0.30], "scatter area: x min, max (m)")
        d("play_y", [-0.16, 0.16], "scatter area: y min, max (m)")
        d("play_radius", [0.14, 0.285],
          "scatter area: distance from the pan axis min, max (m); a top-down pick reaches 0.285")

    # ------------------------------------------------------------------ stepping thread
    def _loop(self) -> None:
        world = self.world
        chunk = max(1, int(round(world.cfg.physics_rate / self.clock_rate)))
        fast_chunk = max(chunk, int(round(world.cfg.physics_rate * 0.02)))
        ref_wall, ref_sim, fast_before = time.monotonic(), world.time, None
        last_notify = 0.0
        while self._running:
            with self.lock:
                was_busy = world.busy
                fast = self.rtf == 0.0 and was_busy
                if fast != fast_before:  # re-anchor the pace when switching modes
                    ref_wall, ref_sim, fast_before = time.monotonic(), world.time, fast
                rate = 1.0 if self.rtf == 0.0 else self.rtf
                behind = ref_sim + (time.monotonic() - ref_wall) * rate - world.time
                if behind > 0.25 * rate:  # cannot keep the pace: drop the debt, do not race
                    ref_wall, ref_sim, behind = time.monotonic(), world.time, world.dt * chunk
                owed = fast or behind >= world.dt * chunk
                if owed:
                    world.step(fast_chunk if fast else chunk)
                finished = was_busy and not world.busy
                if owed:
                    self._publish_due(force_joints=finished)
            now = time.monotonic()
            # Wake waiting action callbacks when a motion ends, and now and then for feedback.
            if finished or now - last_notify > 0.05:
                with self._stepped:
                    self._stepped.notify_all()
                last_notify = now
                time.sleep(0)  # let them take the GIL
            if not owed:
                time.sleep(min(0.005, world.dt * chunk / rate))

    def _publish_due(self, force_joints: bool = False) -> None:
        """Publish what is due in simulated time. Running far faster than real time, /clock and
        joint_states are also capped in wall time (1 kHz and 100 Hz): more would only load the
        subscribers, and a motion's end always publishes the final joint state."""
        t = self.world.time
        n = self._next
        wall = time.monotonic()
        if self.clock_pub is not None and t >= n["clock"] and wall >= n["clock_wall"]:
            self.clock_pub.publish(Clock(clock=_stamp(t)))
            n["clock"] = t + 1.0 / self.clock_rate
            n["clock_wall"] = wall + 0.001
        if force_joints or (t >= n["joints"] and wall >= n["joints_wall"]):
            self._publish_joints()
            n["joints"] = t + 1.0 / self.joint_state_rate
            n["joints_wall"] = wall + 0.01
        if t >= n["truth"]:
            self._publish_truth()
            n["truth"] = t + 1.0 / self.ground_truth_rate
        if self.camera_rate > 0 and t >= n["camera"]:
            # Render only for subscribers, and at most camera_rate times per wall second too.
            wall = time.monotonic()
            if wall - self._last_render_wall >= 1.0 / self.camera_rate:
                if (self.image_pub.get_subscription_count() > 0
                        or self.info_pub.get_subscription_count() > 0):
                    self._publish_image()
                self._last_render_wall = wall
                n["camera"] = t + 1.0 / self.camera_rate

    def _publish_joints(self) -> None:
        pos, vel, eff = self.world.joint_state()
        msg = JointState()
        msg.header.stamp = _stamp(self.world.time)
        msg.name = list(m.ALL_JOINTS)
        msg.position, msg.velocity, msg.effort = pos.tolist(), vel.tolist(), eff.tolist()
        self.joint_pub.publish(msg)

    def camera_info_msg(self) -> CameraInfo:
        cam = self.world.camera
        info = CameraInfo()
        info.header.frame_id = cam.frame_id
        info.width, info.height = cam.width, cam.height
        info.distortion_model = "plumb_bob"
        info.d = [0.0] * 5
        info.k = cam.K.ravel().tolist()
        info.r = np.eye(3).ravel().tolist()
        info.p = cam.P.ravel().tolist()
        return info

    def _publish_image(self) -> None:
        img = self.world.render()
        stamp = _stamp(self.world.time)
        msg = Image()
        msg.header.stamp = stamp
        msg.header.frame_id = self.world.camera.frame_id
        msg.height, msg.width = img.shape[:2]
        msg.encoding = "rgb8"
        msg.is_bigendian = 0
        msg.step = img.shape[1] * 3
        msg.data = img.tobytes()
        info = self.camera_info_msg()
        info.header.stamp = stamp
        self.image_pub.publish(msg)
        self.info_pub.publish(info)

    def ground_truth_msg(self) -> BlockArray:
        """The true scene as a BlockArray (thread-safe: PyBullet is used under the lock)."""
        with self.lock:
            truth, stamp = self.world.ground_truth(), _stamp(self.world.time)
        arr = BlockArray()
        arr.header.stamp = stamp
        arr.header.frame_id = self.world_frame
        for b in truth:
            blk = Block()
            blk.id, blk.color = b.id, b.color
            pose = Pose()
            pose.position.x, pose.position.y, pose.position.z = b.position
            (pose.orientation.x, pose.orientation.y, pose.orientation.z,
             pose.orientation.w) = b.quaternion
            blk.pose = pose
            blk.size.x, blk.size.y, blk.size.z = b.size
            blk.yaw, blk.level, blk.on_top, blk.visible = b.yaw, b.level, b.on_top, b.visible
            blk.pixel_u, blk.pixel_v, blk.pixel_angle = b.pixel_u, b.pixel_v, b.pixel_angle
            arr.blocks.append(blk)
        return arr

    def _publish_truth(self) -> None:
        self.truth_pub.publish(self.ground_truth_msg())

    def _wait(self, handle, wall_budget: float, goal_handle, on_tick=None):
        """Wait (bounded) for a motion handle; returns 'done', 'canceled' or 'timeout'."""
        deadline = time.monotonic() + wall_budget
        next_tick = 0.0
        while not handle.outcome.done:
            if goal_handle.is_cancel_requested:
                return "canceled"
            if time.monotonic() > deadline or not self._running:
                return "timeout"
            if on_tick is not None and time.monotonic() >= next_tick:
                on_tick()
                next_tick = time.monotonic() + 0.1
            with self._stepped:
                self._stepped.wait(timeout=0.05)
        return "done"

    def _wall_budget(self, sim_seconds: float) -> float:
        return (sim_seconds + 10.0) / (self.rtf if self.rtf > 0 else 1.0)

    # ------------------------------------------------------------------ actions
    def _accept(self, _goal) -> GoalResponse:
        return GoalResponse.ACCEPT  # validated in execute, so a refusal carries its reason

    def _cancel(self, _goal_handle) -> CancelResponse:
        return CancelResponse.ACCEPT

    def _execute_trajectory(self, goal_handle):
        req = goal_handle.request
        result = FollowJointTrajectory.Result()
        traj = req.trajectory
        points = traj.points
        n = len(traj.joint_names)
        use_vel = bool(points) and all(len(pt.velocities) == n for pt in points)
        goal = TrajectoryGoal(
            joint_names=list(traj.joint_names),
            times=[_duration(pt.time_from_start) for pt in points],
            positions=[list(pt.positions) for pt in points],
            velocities=[list(pt.velocities) for pt in points] if use_vel else None,
            goal_tolerance={t.name: t.position for t in req.goal_tolerance},
            path_tolerance={t.name: t.position for t in req.path_tolerance},
            goal_time_tolerance=_duration(req.goal_time_tolerance),
        )
        with self.lock:
            handle = self.world.start_trajectory(goal)
        if handle.outcome.done:
            result.error_code = handle.outcome.error_code
            result.error_string = handle.outcome.message
            self.get_logger().warning(f"trajectory refused: {result.error_string}")
            goal_handle.abort()
            return result
        follower = handle.controller

        def feedback() -> None:
            with self.lock:
                t = self.world.time
                desired, _ = follower.sample(t)
                pos = self.world.joint_positions()
            fb = FollowJointTrajectory.Feedback()
            fb.header.stamp = _stamp(t)
            fb.joint_names = follower.names
            actual = [pos[j] for j in follower.names]
            fb.desired = JointTrajectoryPoint(positions=desired.tolist())
            fb.actual = JointTrajectoryPoint(positions=actual)
            fb.error = JointTrajectoryPoint(positions=(np.array(actual) - desired).tolist())
            goal_handle.publish_feedback(fb)

        budget = self._wall_budget(follower.duration + follower.goal_time)
        state = self._wait(handle, budget, goal_handle, feedback)
        if state != "done":
            with self.lock:
                self.world.cancel_trajectory(state, only=handle)
            if state == "canceled":
                result.error_string = "canceled"
                goal_handle.canceled()
            else:
                result.error_code = ctl.GOAL_TOLERANCE_VIOLATED
                result.error_string = f"no outcome within {budget:.1f} s (wall)"
                goal_handle.abort()
            return result
        out = handle.outcome
        result.error_code = out.error_code
        result.error_string = out.message
        if out.status == ctl.SUCCEEDED:
            goal_handle.succeed()
        else:
            if out.status == ctl.CANCELED and not result.error_string:
                result.error_string = "preempted"
            goal_handle.abort()
        return result

    def _execute_gripper(self, goal_handle):
        cmd = goal_handle.request.command
        result = GripperCommand.Result()
        lo, hi = m.GRIPPER_CLOSED, m.GRIPPER_OPEN
        if not (math.isfinite(cmd.position) and math.isfinite(cmd.max_effort)) or not (
            lo - 1e-3 <= cmd.position <= hi + 1e-3) or cmd.max_effort < 0:
            self.get_logger().warning(
                f"gripper goal refused: position {cmd.position} must be in [{lo}, {hi}] and "
                f"max_effort {cmd.max_effort} finite and >= 0")
            with self.lock:
                result.position = float(np.mean(self.world.joint_state()[0][5:]))
            goal_handle.abort()
            return result
        with self.lock:
            handle = self.world.start_gripper(cmd.position, cmd.max_effort)
        ctrl = handle.controller

        def feedback() -> None:
            with self.lock:
                pos = float(np.mean(self.world.joint_state()[0][5:]))
            goal_handle.publish_feedback(
                GripperCommand.Feedback(position=pos, effort=ctrl.effort, stalled=False,
                                        reached_goal=False))

        budget = self._wall_budget(ctrl.ramp_end - ctrl.t0 + ctrl.timeout + 1.0)
        state = self._wait(handle, budget, goal_handle, feedback)
        if state != "done":
            with self.lock:
                self.world.cancel_gripper(only=handle)
                result.position = float(np.mean(self.world.joint_state()[0][5:]))
            if state == "canceled":
                goal_handle.canceled()
            else:
                goal_handle.abort()
            return result
        out = handle.outcome
        result.position, result.effort = out.position, out.effort
        result.stalled, result.reached_goal = out.stalled, out.reached_goal
        if out.status == ctl.SUCCEEDED:
            goal_handle.succeed()
        else:
            goal_handle.abort()
        return result

    def _reset(self, request, response):
        try:
            with self.lock:
                self.world.cancel_trajectory("world reset")
                self.world.cancel_gripper()
                self.world.reset(None if request.seed < 0 else int(request.seed))
                self._publish_truth()
                seed = self.world.last_seed
        except RuntimeError as exc:
            response.success, response.message = False, str(exc)
            return response
        response.success = True
        response.message = f"scattered {len(self.world.blocks)} blocks with seed {seed}"
        self.get_logger().info(response.message)
        return response

    def destroy_node(self) -> None:
        self._running = False
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        with self.lock:
            self.world.close()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    rclpy.init(args=args)
    try:
        node = SimNode()
    except Exception as exc:  # invalid parameters: say which, exit non-zero
        print(f"sim_node: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    executor = MultiThreadedExecutor(num_threads=4)
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
