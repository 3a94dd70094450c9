"""The PyBullet physics of the Katana, its table and blocks. ROS-free; `sim_node` is a thin wrapper.

Usage (also for scripted scenes in other packages' tests):

    from katana_sim.core import PhysicsSim, SimConfig
    world = PhysicsSim(SimConfig(num_blocks=4, seed=1))  # DIRECT mode, no display
    world.reset(seed=7)                    # scatter the blocks (seeded), park the arm
    rgb = world.render()                   # np.uint8 (480, 640, 3), overhead camera
    cam = world.camera                     # CameraModel: K, P, pose, project(), pixel_to_plane()
    blocks = world.ground_truth()          # list[BlockState]: id, colour, position, yaw, level,
                                           #   on_top, visible, pixel_u/v/angle, quaternion, size
    world.set_block_pose("red", (0.2, 0.0, 0.015), yaw=0.3)   # teleport (centre, metres)
    world.stack("green", on="red", dx=0.0, dy=0.0)            # put one block on another
    world.step(240)                        # advance physics (1/physics_rate s per step)
    world.settle()                         # step until every block is at rest (bounded)
    world.advance_clock(0.5)               # let simulated time pass with the world frozen
    world.set_arm_positions(q5)            # teleport the arm (and hold it there)
    world.close()

Arm control: `start_trajectory(TrajectoryGoal)` and `start_gripper(position, effort)` return a
handle whose `.outcome` says when the motion is done; stepping the world advances them. The
motors are PyBullet position motors fed a target that moves within the joint speed limits, with
torques far above what gravity needs (katana_description.models.SIM_MOTOR_TORQUE). Blocks are held
by contact and friction only: nothing welds a block to the hand. Through free space
(`SimConfig.kinematic_free_space`, on by default) the arm follows its plan without physics
steps, and a block held still between both finger pads rides in its grip: `step()` says when.

Ground truth (levels, visibility) is core.ground_truth's, from the block poses.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pybullet as p
from katana_description import arm_contract as ac
from katana_description import gripper_contract as gc
from katana_description import models as m
from katana_description import urdf_gen, urdf_path
from katana_description.arm_contract import complete_trajectory as ctl_complete
from katana_description.arm_contract import validate_trajectory as ctl_validate
from katana_description.gripper_contract import validate_gripper as ctl_validate_gripper

from katana_sim.core import controllers as ctl
from katana_sim.core.camera import CameraModel
from katana_sim.core.config import SimConfig
from katana_sim.core.ground_truth import BlockState, block_states, yaw_of

FINGER_PAD_LINKS = ("katana_r_finger_link", "katana_l_finger_link")
#: the arm's links from this one out reach over the table (arm_in_view)
FIRST_REACHING_LINK = "katana_motor3_lift_link"
#: a block slower than this, and turning slower than this, is at rest
REST_SPEED_M_S = 2e-3
REST_SPIN_RAD_S = 2e-2
#: clearance (m) the arm keeps, at the poses checked, from every block and from the table top
#: while it moves along its plan without physics steps (`PhysicsSim.step`); between two poses
#: checked it keeps at least half of it. Bullet's solver pushes two shapes apart only when
#: they would touch within the step: 5 mm in a step is 1.2 m/s at 240 Hz, and no link of a
#: pick-and-place moves faster than 0.40 m/s (bench_arm's 64 trials, stepped in physics).
FREE_SPACE_MARGIN_M = 0.01
#: a bound (m) on how far a point of the arm moves per radian of any joint: the Katana's
#: longest lever, from the shoulder's axis to the fingertips, is about 0.6 m
ARM_LEVER_M = 0.7


def _riding_velocity(link_state, point) -> tuple[np.ndarray, np.ndarray]:
    """Linear and angular velocity of a point fixed to a link, from its getLinkState with
    computeLinkVelocity (the linear velocity there is its centre of mass's)."""
    w = np.array(link_state[7])
    return np.array(link_state[6]) + np.cross(w, np.subtract(point, link_state[0])), w


class _Refused:
    """The stand-in controller of a goal refused before it started."""

    def __init__(self, outcome) -> None:
        self.outcome = outcome


class ArmHandle:
    """A running arm or gripper motion; `.outcome` is updated as the world steps."""

    def __init__(self, controller) -> None:
        self.controller = controller

    @property
    def outcome(self):
        return self.controller.outcome


class PhysicsSim:
    def __init__(self, config: SimConfig | None = None) -> None:
        self.cfg = (config or SimConfig()).validate()
        self.camera: CameraModel = self.cfg.camera
        self.contract = ac.ArmContract(model=self.cfg.model)
        self.dt = 1.0 / self.cfg.physics_rate
        # Simulated time is whole physics steps plus idle time (advance_clock); motions run on
        # step counts, so a motion's targets are bit-for-bit the same whatever time it starts at
        # (float time since start-up would round differently after a different history).
        self._steps = 0
        self._idle_s = 0.0
        self._cid = p.connect(p.DIRECT)
        self._probe_cid: int | None = None  # the arm alone, for the free-space check
        self.physics_steps = 0  # steps made by the physics engine
        self.kinematic_steps = 0  # steps the arm or the fingers moved without physics
        # counts what can move the world but the arm's free moves: physics steps and teleports
        self._changes = 0
        self._horizon: tuple | None = None  # (trajectory, changes, last free step, held)
        self._not_free: tuple | None = None  # (trajectory, changes, steps) found not free
        self._finger_horizon: tuple | None = None  # (gripper goal, free, changes if free)
        self._tmp = tempfile.TemporaryDirectory(prefix="katana_sim_")
        self._rng = np.random.default_rng(self.cfg.seed)
        self._trajectory: ctl.TrajectoryFollower | None = None
        self._gripper: ctl.GripperController | None = None
        self._rendered: tuple[tuple, np.ndarray] | None = None  # (scene key, image)
        self._in_view: tuple[tuple[int, int], bool] | None = None  # (steps, changes), answer
        self.reset(self.cfg.seed)
        self._build_probe()

    # ------------------------------------------------------------------ construction
    def _pb(self, fn, *args, **kwargs):
        return fn(*args, physicsClientId=self._cid, **kwargs)

    def _write(self, name: str, text: str) -> str:
        path = Path(self._tmp.name) / name
        path.write_text(text)
        return str(path)

    def _build(self) -> None:
        cfg = self.cfg
        self._pb(p.setGravity, 0, 0, -9.81)
        self._pb(p.setTimeStep, self.dt)
        self._pb(p.setPhysicsEngineParameter, numSolverIterations=20,
                 deterministicOverlappingPairs=1)
        self.table = self._pb(p.loadURDF, self._write("table.urdf", urdf_gen.table_urdf()),
                              useFixedBase=True)
        self._prepare_table_render()
        self._arm_file = cfg.arm_urdf or str(
            urdf_path(f"katana_{m.get_model(cfg.model).name}.urdf"))
        self.arm = self._pb(p.loadURDF, self._arm_file, (0, 0, 0), useFixedBase=True,
                            flags=p.URDF_USE_INERTIA_FROM_FILE)
        self.joint_index: dict[str, int] = {}
        self.link_index: dict[str, int] = {}
        for i in range(self._pb(p.getNumJoints, self.arm)):
            info = self._pb(p.getJointInfo, self.arm, i)
            self.joint_index[info[1].decode()] = i
            self.link_index[info[12].decode()] = i
        self._arm_idx = [self.joint_index[n] for n in m.ARM_JOINTS]
        self._finger_idx = [self.joint_index[n] for n in m.FINGER_JOINTS]
        self._all_idx = self._arm_idx + self._finger_idx
        self._forces = [m.SIM_MOTOR_TORQUE[n] for n in m.ALL_JOINTS]
        # One motor drives both fingers on the real gripper: couple the two finger joints with a
        # gear constraint (an internal linkage of the hand, not a tie to any block).
        gear = self._pb(p.createConstraint, self.arm, self._finger_idx[0], self.arm,
                        self._finger_idx[1], p.JOINT_GEAR, (0, 0, 1), (0, 0, 0), (0, 0, 0))
        self._pb(p.changeConstraint, gear, gearRatio=-1.0, maxForce=50.0, erp=0.8)
        for link in FINGER_PAD_LINKS:
            self._pb(p.changeDynamics, self.arm, self.link_index[link],
                     lateralFriction=cfg.finger_friction, spinningFriction=0.01,
                     frictionAnchor=1)
        self.blocks: dict[str, int] = {}
        for colour in cfg.colours:
            text = urdf_gen.block_urdf(colour, cfg.block_size, cfg.block_mass, m.COLOURS[colour])
            body = self._pb(p.loadURDF, self._write(f"block_{colour}.urdf", text), (0, 0, -1))
            # Bullet's sleeping: a block at rest is not integrated until something touches it
            # (about a third of a step's cost with four blocks; deterministic).
            self._pb(p.changeDynamics, body, -1, lateralFriction=cfg.block_friction,
                     spinningFriction=0.001, rollingFriction=0.0, restitution=0.0,
                     activationState=p.ACTIVATION_STATE_ENABLE_SLEEPING)
            self.blocks[colour] = body
        self._targets = np.zeros(len(self._all_idx))
        self._target_vel = np.zeros(len(self._all_idx))
        self._finger_effort = cfg.gripper_effort
        self._table_top_z = self._pb(p.getAABB, self.table, -1)[1][2]

    def _build_probe(self) -> None:
        """A second world holding only the arm, posed along a plan by the free-space check, so
        that the check never touches the simulated arm's state. Links with a collision shape
        that can move (the base is bolted to the table) are the ones checked."""
        self._probe_cid = p.connect(p.DIRECT)
        self._probe_arm = p.loadURDF(self._arm_file, (0, 0, 0), useFixedBase=True,
                                     physicsClientId=self._probe_cid)
        # copies of the blocks, posed as the real ones (or in the grip) for exact distances
        self._probe_blocks = {
            body: p.loadURDF(str(Path(self._tmp.name) / f"block_{colour}.urdf"), (0, 0, -1),
                             physicsClientId=self._probe_cid)
            for colour, body in self.blocks.items()}
        self._gripper_link = self.link_index["katana_gripper_link"]
        self._pad_links = [self.link_index[name] for name in FINGER_PAD_LINKS]
        self._probe_links = [i for i in range(self._pb(p.getNumJoints, self.arm))
                             if self._pb(p.getCollisionShapeData, self.arm, i)]
        first = self.link_index[FIRST_REACHING_LINK]
        self._reaching_links = [i for i in self._probe_links if i >= first]
        # the arm joints (ALL_JOINTS order) whose links come before the reaching ones
        self._joints_before_reaching = sum(1 for i in self._all_idx if i < first)

    def close(self) -> None:
        for cid in (self._cid, self._probe_cid):
            if cid is not None and p.isConnected(cid):
                p.disconnect(cid)
        self._cid = self._probe_cid = None
        self._tmp.cleanup()

    def __del__(self) -> None:  # best effort; explicit close() is preferred
        try:
            self.close()
        except Exception:
            pass

    # ------------------------------------------------------------------ scene
    def scatter_poses(self, seed: int) -> list[tuple[float, float, float]]:
        """Seeded, non-overlapping (x, y, yaw) per block, inside the play area and the image."""
        cfg = self.cfg
        rng = np.random.default_rng(seed)
        sx, sy, sz = cfg.block_size
        radius = 0.5 * math.hypot(sx, sy)
        min_dist = 2 * radius + cfg.min_gap
        for _ in range(200):
            poses: list[tuple[float, float, float]] = []
            for _block in cfg.colours:
                for _try in range(500):
                    x = rng.uniform(*cfg.play_x)
                    y = rng.uniform(*cfg.play_y)
                    if not cfg.play_radius[0] <= math.hypot(x, y) <= cfg.play_radius[1]:
                        continue
                    if any(math.hypot(x - a, y - b) < min_dist for a, b, _ in poses):
                        continue
                    corners = np.array([[x + dx, y + dy, sz] for dx in (-radius, radius)
                                        for dy in (-radius, radius)])
                    if not self.camera.in_view(corners, margin_px=4).all():
                        continue
                    poses.append((x, y, float(rng.uniform(-math.pi / 4, math.pi / 4))))
                    break
                else:
                    break
            if len(poses) == len(cfg.colours):
                return poses
        raise RuntimeError("could not scatter the blocks without overlap: play area too small")

    def reset(self, seed: int | None = None) -> list[BlockState]:
        """Scatter the blocks (seed None: the next seed of this world's own sequence), park the
        arm with the gripper open, and let everything settle."""
        if seed is None or seed < 0:
            seed = int(self._rng.integers(0, 2**31 - 1))
        self.last_seed = int(seed)
        # A fresh physics world, so that a seed gives the same episode whatever came before
        # (contact caches and solver warm starts carry history otherwise).
        self._pb(p.resetSimulation)
        self._build()
        self._trajectory = None
        self._gripper = None
        self.set_arm_positions(m.PARK_POSE, m.GRIPPER_OPEN)
        half = self.cfg.block_size[2] / 2
        for colour, (x, y, yaw) in zip(self.cfg.colours, self.scatter_poses(seed), strict=True):
            self.set_block_pose(colour, (x, y, half), yaw)
        self.step(int(0.1 / self.dt))
        return self.ground_truth()

    def set_block_pose(self, block_id: str, position, yaw: float = 0.0,
                       quaternion=None) -> None:
        """Teleport a block (centre position, metres) and stop it."""
        body = self.blocks[block_id]
        self._changes += 1
        quat = quaternion if quaternion is not None else p.getQuaternionFromEuler((0, 0, yaw))
        self._pb(p.resetBasePositionAndOrientation, body, tuple(position), tuple(quat))
        self._pb(p.resetBaseVelocity, body, (0, 0, 0), (0, 0, 0))

    def stack(self, block_id: str, on: str, dx: float = 0.0, dy: float = 0.0,
              yaw: float | None = None) -> None:
        """Put block_id on top of block `on`, offset by (dx, dy) metres in the world frame."""
        pos, quat = self._pb(p.getBasePositionAndOrientation, self.blocks[on])
        top_yaw = yaw_of(quat) if yaw is None else yaw
        h = self.cfg.block_size[2]
        self.set_block_pose(block_id, (pos[0] + dx, pos[1] + dy, pos[2] + h + 1e-4), top_yaw)

    def block_pose(self, block_id: str) -> tuple[np.ndarray, np.ndarray]:
        pos, quat = self._pb(p.getBasePositionAndOrientation, self.blocks[block_id])
        return np.array(pos), np.array(quat)

    def blocks_at_rest(self) -> bool:
        return all(self._at_rest(body) for body in self.blocks.values())

    def _at_rest(self, body: int) -> bool:
        lin, ang = self._pb(p.getBaseVelocity, body)
        return np.linalg.norm(lin) <= REST_SPEED_M_S and np.linalg.norm(ang) <= REST_SPIN_RAD_S

    def settle_motion(self, max_time: float = 2.0) -> None:
        """After a motion: step until every block is at rest (bounded by max_time simulated s).

        The fast sim freezes physics while idle (`advance_clock`), so a motion only ends once
        nothing moves any more: a released block has landed, a stack has toppled or stood. The
        checks are every 0.05 s of simulated time, so the number of steps depends only on the
        state, never on wall-clock timing."""
        chunk = max(1, int(round(0.05 / self.dt)))
        t_end = self.time + max_time
        while not self.blocks_at_rest() and self.time < t_end:
            self.step(chunk)

    def advance_clock(self, seconds: float) -> None:
        """Let simulated time pass without stepping physics (the fast sim while idle, after
        `settle_motion`): the motors hold, nothing moves, images and stamps go on."""
        if seconds > 0:
            self._idle_s += seconds

    def settle(self, max_time: float = 3.0, min_time: float = 0.2) -> bool:
        """Step until every block is at rest (True) or max_time simulated seconds passed."""
        self.step(int(min_time / self.dt))
        chunk = max(1, int(0.05 / self.dt))
        t_end = self.time + max_time
        while self.time < t_end:
            if self.blocks_at_rest():
                return True
            self.step(chunk)
        return self.blocks_at_rest()

    # ------------------------------------------------------------------ arm
    def set_arm_positions(self, arm_q, fingers: float | None = None) -> None:
        """Teleport the arm (five angles) and, if given, the fingers; the motors hold there."""
        q = list(arm_q)[:5]
        self._changes += 1
        for idx, v in zip(self._arm_idx, q, strict=True):
            self._pb(p.resetJointState, self.arm, idx, v, 0.0)
        self._targets[:5] = q
        self._target_vel[:] = 0.0
        if fingers is not None:
            for idx in self._finger_idx:
                self._pb(p.resetJointState, self.arm, idx, fingers, 0.0)
            self._targets[5:] = fingers
        self._trajectory = None
        self._gripper = None

    def joint_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions, velocities and motor torques of the seven joints (ALL_JOINTS order)."""
        states = self._pb(p.getJointStates, self.arm, self._all_idx)
        pos = np.array([s[0] for s in states])
        vel = np.array([s[1] for s in states])
        eff = np.array([s[3] for s in states])
        return pos, vel, eff

    def joint_positions(self) -> dict[str, float]:
        pos, _, _ = self.joint_state()
        return dict(zip(m.ALL_JOINTS, pos.tolist(), strict=True))

    def link_pose(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        """World position and quaternion of an arm link frame (PyBullet's own FK)."""
        state = self._pb(p.getLinkState, self.arm, self.link_index[link],
                         computeForwardKinematics=True)
        return np.array(state[4]), np.array(state[5])

    def tool_pose(self) -> tuple[np.ndarray, np.ndarray]:
        return self.link_pose("katana_gripper_tool_frame")

    def start_trajectory(self, goal: ac.TrajectoryGoal) -> ArmHandle:
        """Validate (the arm contract) and start a trajectory, preempting a running one. A
        refused goal returns a handle that is already done, with the error code and reason.
        Joints a partial goal leaves out hold where they are."""
        current = self.joint_positions()
        verdict = ctl_validate(goal, current, self.contract)
        if not verdict.ok:
            return ArmHandle(_Refused(ctl.refused(verdict.error_code, verdict.error_string)))
        self.cancel_trajectory("preempted by a new goal")
        full = ctl_complete(goal, current)
        fingers = sum(current[n] for n in m.FINGER_JOINTS) / len(m.FINGER_JOINTS)
        follower = ctl.TrajectoryFollower(full, self.contract, 0.0, self._targets[:5], fingers)
        follower.start_step = self._steps
        self._trajectory = follower
        return ArmHandle(follower)

    def cancel_trajectory(self, reason: str = "canceled", only: ArmHandle | None = None) -> None:
        """Stop the running trajectory where the arm is now, and hold (if `only` is given: only
        when that handle's trajectory is the running one)."""
        if (only is not None and only.controller is not self._trajectory) or self._cid is None:
            return
        if self._trajectory is not None and not self._trajectory.outcome.done:
            self._trajectory.judge.cancel(reason)
            pos, _, _ = self.joint_state()
            self._targets[:5] = pos[:5]
            self._target_vel[:5] = 0.0
        self._trajectory = None

    def start_gripper(self, position: float, effort: float = 0.0) -> ArmHandle:
        """Move both fingers towards `position` (rad) with at most `effort` N m (0: default).
        Refused (a handle already done) by the arm contract's rules."""
        goal = gc.GripperGoal(position, effort)
        verdict = ctl_validate_gripper(goal, arm_active=self._trajectory is not None)
        pos, _, _ = self.joint_state()
        if not verdict.ok:
            return ArmHandle(_Refused(gc.GripperOutcome(
                ac.ABORTED, float(pos[5:].mean()), message=verdict.error_string)))
        self.cancel_gripper()
        self._finger_effort = effort if effort > 0 else self.cfg.gripper_effort
        # Start from where the fingers are: a target squeezing a block lies past them.
        ctrl = ctl.GripperController(goal, self.contract, 0.0, float(pos[5:].mean()))
        ctrl.start_step = self._steps
        self._gripper = ctrl
        return ArmHandle(ctrl)

    def cancel_gripper(self, only: ArmHandle | None = None) -> None:
        """Stop the fingers where they are (if `only` is given: only that motion)."""
        if (only is not None and only.controller is not self._gripper) or self._cid is None:
            return
        if self._gripper is not None and not self._gripper.outcome.done:
            pos, _, _ = self.joint_state()
            self._gripper.cancel(float(pos[5:].mean()))
            self._targets[5:] = pos[5:].mean()
        self._gripper = None

    @property
    def time(self) -> float:
        """Simulated seconds since start-up (the stamps and /clock)."""
        return self._steps * self.dt + self._idle_s

    def elapsed(self, controller) -> float:
        """Simulated seconds since a motion started, from whole steps."""
        return (self._steps - controller.start_step) * self.dt

    @property
    def busy(self) -> bool:
        """True while an arm or gripper motion is running."""
        return (self._trajectory is not None and not self._trajectory.outcome.done) or (
            self._gripper is not None and not self._gripper.outcome.done
        )

    # ------------------------------------------------------------------ stepping
    def free_run(self, chunk: int) -> int:
        """Steps, in whole chunks of `chunk`, that the running trajectory will now make without
        physics (`step`) with every chunk's end before the end of its plan: the fast sim's
        lock-step takes them in one `step` call (`pacing.run_motion`). Judged chunk by chunk,
        the arm would be on its plan at each of those ends, where only the path tolerances are
        checked, so the outcome, the steps and the state after are the same; what is spared is
        the per-chunk work in Python (sampling the plan, posing the arm, judging, publishing).
        0 when the arm may not move without physics, or no whole chunk is left."""
        traj = self._trajectory
        if traj is None or traj.outcome.done or chunk <= 0:
            return 0
        free, _ = self._free_steps(traj, 1 << 62)
        elapsed = self._steps - traj.start_step
        duration = traj.judge.duration_s
        chunks = min(free // chunk, max(0, math.ceil((duration / self.dt - elapsed) / chunk)))
        # chunk ends strictly before the plan's end (judged against the goal from there on),
        # compared as the judge compares them
        while chunks > 0 and (elapsed + chunks * chunk) * self.dt >= duration:
            chunks -= 1
        return chunks * chunk

    def step(self, n: int = 1) -> None:
        """Advance n physics steps, driving the motors from the active controllers.

        While the arm moves through free space (`_free_steps`) the steps are made without
        physics: the arm takes its planned state, where its motors track it to within their lag,
        the block it holds rides in its grip, and nothing else could have moved. So do the
        fingers of an empty hand that open or close clear of every block
        (`_free_finger_steps`): physics steps there would only let blocks that have just come
        to rest creep, by amounts an image made before or after the grip would tell apart."""
        traj, grip = self._trajectory, self._gripper
        if traj is not None:
            free, held = self._free_steps(traj, n)
            if free:
                q, v = traj.sample_many(
                    np.array([(self._steps + free - traj.start_step) * self.dt]))
                self._move_kinematic(free, q[0], v[0], held)
                self._check_controllers(q[0])
                n -= free
        elif grip is not None:
            free = self._free_finger_steps(grip, n)
            if free:
                self._move_fingers_kinematic(free, grip)
                self._check_controllers()
                n -= free
                if self._gripper is None:  # done clear of everything: the rest stands still
                    self._steps += n
                    self.kinematic_steps += n
                    n = 0
        if n > 0:
            self._step_physics(n)

    def _step_physics(self, n: int) -> None:
        forces = list(self._forces)
        forces[5] = forces[6] = self._finger_effort
        check_every = max(1, int(round(0.01 / self.dt)))
        cid, arm, idx = self._cid, self.arm, self._all_idx
        kp, kd = [0.3] * 7, [1.0] * 7
        traj = self._trajectory
        if traj is not None:  # completed goals: all five arm joints, ARM_JOINTS order
            plan_q, plan_v = traj.sample_many(
                (self._steps - traj.start_step + np.arange(n + 1)) * self.dt)  # as elapsed()
        for k in range(n):
            traj, grip = self._trajectory, self._gripper  # a check below may end either
            if traj is not None:
                self._targets[:5], self._target_vel[:5] = plan_q[k], plan_v[k]
            if grip is not None:
                self._targets[5] = self._targets[6] = grip.target(self.elapsed(grip))
            p.setJointMotorControlArray(
                arm, idx, p.POSITION_CONTROL, targetPositions=self._targets.tolist(),
                targetVelocities=self._target_vel.tolist(), forces=forces, positionGains=kp,
                velocityGains=kd, physicsClientId=cid)
            p.stepSimulation(physicsClientId=cid)
            self._steps += 1
            self.physics_steps += 1
            self._changes += 1
            if (traj is not None or grip is not None) and (k == n - 1 or k % check_every == 0):
                # judged against the plan at the time reached (the step just made)
                self._check_controllers(plan_q[k + 1] if traj is not None else None)

    def _free_steps(self, traj, n: int) -> tuple[int, tuple]:
        """How many of the next n steps the arm may make without physics, and the block it
        carries as (body, pose in the gripper's frame), or () for an empty hand.

        It may when the fingers are still, every block is at rest but one held still between
        both finger pads, and the arm and the block it holds, where they are and posed at
        samples of the plan, keep FREE_SPACE_MARGIN_M from every other block and from the table
        top (`_clearance`, a lower bound on the distance: the check may miss a free move, never
        admit one that comes near anything). Samples advance by conservative advancement: no
        point of the arm moves further than ARM_LEVER_M times the joints' summed travel, so
        from a sample with `spare` metres beyond the margin the next may lie `spare` plus half
        the margin on (plus one step's motion), and every pose between keeps half the margin.
        What it admits holds up to the horizon it found (nothing but the arm and its load moves
        meanwhile), unless something is teleported or the fingers start."""
        if not self.cfg.kinematic_free_space or self._gripper is not None:
            return 0, ()
        horizon = self._horizon
        if (horizon is not None and horizon[0] is traj and horizon[1] == self._changes
                and self._steps < horizon[2]):
            return min(n, horizon[2] - self._steps), horizon[3]
        self._horizon = None
        key = (traj, self._changes, self._steps)
        refused = self._not_free
        if refused is not None and refused[0] is traj and refused[1:] == key[1:]:
            return 0, ()  # found not free in this state already (free_run, then step)
        self._not_free = key  # until a horizon is found below
        held = self._held_block()
        if held is None:
            return 0, ()
        others = [body for body in self.blocks.values() if not held or body != held[0]]
        if not all(self._at_rest(body) for body in others):
            return 0, ()
        obstacles = self._obstacles(others)
        if self._clearance(self._cid, self.arm, held, obstacles) < 0:  # where the arm is now
            return 0, ()
        # the rest of the plan, its end included (the arm holds there once it is done)
        start = self._steps - traj.start_step
        rows_left = max(1, math.ceil(traj.duration / self.dt) - start)
        plan_q, _ = traj.sample_many((start + np.arange(rows_left + 1)) * self.dt)
        moved = np.abs(np.diff(plan_q, axis=0)).sum(axis=1) * ARM_LEVER_M
        travelled = np.concatenate(([0.0], np.cumsum(moved)))
        probe, arm = self._probe_cid, self._probe_arm
        probe_obstacles = self._probe_obstacles(others, obstacles)
        probe_held = (self._probe_blocks[held[0]], *held[1:]) if held else ()
        fingers = self.joint_state()[0][5:]  # still while the arm moves without physics
        p.resetJointStatesMultiDof(arm, self._finger_idx, [[v] for v in fingers],
                                   physicsClientId=probe)
        last, row = 0, 0  # every sample up to row `last` is clear
        while True:
            p.resetJointStatesMultiDof(arm, self._arm_idx, [[v] for v in plan_q[row]],
                                       physicsClientId=probe)
            spare = self._clearance(probe, arm, probe_held, probe_obstacles)
            if spare < 0:
                break
            last = row
            if row >= rows_left:
                last = 1 << 62  # the end is clear too: free until the goal is judged
                break
            # no point moves further than the travel bound: up to `spare` + margin / 2 on,
            # every pose keeps half the margin
            reach = travelled[row] + spare + FREE_SPACE_MARGIN_M / 2
            row = min(rows_left, max(row + 1, int(np.searchsorted(travelled, reach, "right")) - 1))
        if last > 0:  # later calls find it without checking again while nothing else moves
            self._not_free = None
            self._horizon = (traj, self._changes, self._steps + last, held)
        return min(n, last), held

    def _free_finger_steps(self, grip, n: int) -> int:
        """How many of the next n steps the fingers of an empty hand may make without physics,
        the arm standing: every block at rest, no block touching the hand, and the arm, posed
        with its fingers at samples of their way to the goal no further apart than
        FREE_SPACE_MARGIN_M / 2 at the arm's longest lever, keeping FREE_SPACE_MARGIN_M from
        every block and from the table top (`_clear`). The steps run to the end of the fingers'
        ramp. The check is made once per goal: a goal found not free is stepped in physics to
        its end (a grasp), one found free is checked again only after something else moved."""
        if not self.cfg.kinematic_free_space:
            return 0
        end_step = grip.start_step + math.ceil(grip.judge.ramp_s / self.dt)
        horizon = self._finger_horizon
        if horizon is not None and horizon[0] is grip:
            if not horizon[1]:  # found not free: the goal is stepped in physics to its end
                return 0
            if horizon[2] == self._changes:
                return min(n, max(0, end_step - self._steps))
        self._finger_horizon = (grip, False)
        if self._steps >= end_step or self._held_block() != ():
            return 0
        if not self.blocks_at_rest():
            return 0
        margin = FREE_SPACE_MARGIN_M
        blocks = list(self.blocks.values())
        obstacles = self._obstacles(blocks)
        if self._clearance(self._cid, self.arm, (), obstacles) < 0:
            return 0
        pos = self.joint_state()[0]
        start, goal = float(pos[5:].mean()), grip.judge.goal
        samples = np.linspace(start, goal, 2 + int(abs(goal - start) / (margin / 2 / ARM_LEVER_M)))
        probe, arm = self._probe_cid, self._probe_arm
        probe_obstacles = self._probe_obstacles(blocks, obstacles)
        p.resetJointStatesMultiDof(arm, self._arm_idx, [[v] for v in pos[:5]],
                                   physicsClientId=probe)
        for angle in samples:
            p.resetJointStatesMultiDof(arm, self._finger_idx, [[angle]] * len(self._finger_idx),
                                       physicsClientId=probe)
            if self._clearance(probe, arm, (), probe_obstacles) < 0:
                return 0
        self._finger_horizon = (grip, True, self._changes)
        return min(n, end_step - self._steps)

    def _move_fingers_kinematic(self, n: int, grip) -> None:
        """n steps without physics: both fingers take the place the finger speed limit gives
        them (the gripper's ideal path; still at its end); nothing else moves."""
        self._steps += n
        self.kinematic_steps += n
        elapsed = self.elapsed(grip)
        angle = grip.target(elapsed)
        speed = 0.0 if elapsed >= grip.judge.ramp_s else math.copysign(
            grip.judge.speed, grip.judge.goal - grip.judge.start)
        fingers = len(self._finger_idx)
        self._pb(p.resetJointStatesMultiDof, self.arm, self._finger_idx, [[angle]] * fingers,
                 [[speed]] * fingers)
        self._targets[5:] = angle
        self._target_vel[5:] = 0.0

    def _held_block(self) -> tuple[int, tuple, tuple] | tuple[()] | None:
        """The block held between both finger pads, moving with the gripper, as (body, pose
        in the gripper's frame); () when no block touches the fingers; None when the hand
        touches a block in another way (a push, a block slipping)."""
        touched = [body for body in self.blocks.values()
                   if self._pb(p.getContactPoints, self.arm, body)]
        if not touched:
            return ()
        if len(touched) > 1:
            return None
        body = touched[0]
        if not all(self._pb(p.getContactPoints, self.arm, body, pad) for pad in self._pad_links):
            return None
        state = self._pb(p.getLinkState, self.arm, self._gripper_link, computeLinkVelocity=1)
        pos, orn = self._pb(p.getBasePositionAndOrientation, body)
        lin, ang = self._pb(p.getBaseVelocity, body)
        riding, w = _riding_velocity(state, pos)
        if (np.linalg.norm(np.subtract(lin, riding)) > REST_SPEED_M_S
                or np.linalg.norm(np.subtract(ang, w)) > REST_SPIN_RAD_S):
            return None
        inv_pos, inv_orn = p.invertTransform(state[4], state[5])
        rel_pos, rel_orn = p.multiplyTransforms(inv_pos, inv_orn, pos, orn)
        return body, rel_pos, rel_orn

    def _obstacles(self, bodies: list[int]) -> tuple[list[int], np.ndarray]:
        """Blocks (at rest) the moving arm must keep FREE_SPACE_MARGIN_M from: their ids and
        their bounding boxes ((b, 2, 3): lower and upper corners)."""
        boxes = np.array([self._pb(p.getAABB, body, -1) for body in bodies]).reshape(-1, 2, 3)
        return list(bodies), boxes

    def _probe_obstacles(self, bodies: list[int], obstacles: tuple) -> tuple:
        """`obstacles` in the probe world: the copies of `bodies` posed where they stand."""
        copies = []
        for body in bodies:
            copy = self._probe_blocks[body]
            p.resetBasePositionAndOrientation(
                copy, *self._pb(p.getBasePositionAndOrientation, body),
                physicsClientId=self._probe_cid)
            copies.append(copy)
        return copies, obstacles[1]

    def _clearance(self, cid: int, arm: int, held, obstacles: tuple) -> float:
        """How much nearer (m) the arm of client `cid` as posed, with the held block (body in
        `cid`, pose in the grip) in its grip, may come to anything before some part of it is
        within FREE_SPACE_MARGIN_M of the table top or of an obstacle block (`_obstacles`, ids
        in `cid`): negative when one is. A lower bound: the table by the parts' bounding boxes;
        a block by the gap between bounding boxes, and where that gap is under the margin by
        PyBullet's exact distance between the shapes (then 0 once it is at least the margin).
        In the main world the held block is where the grip holds it; in the probe world its
        copy is posed there."""
        bodies, boxes_b = obstacles
        boxes = [p.getAABB(arm, i, physicsClientId=cid) for i in self._probe_links]
        if held:
            body = held[0]
            if cid != self._cid:
                state = p.getLinkState(arm, self._gripper_link, physicsClientId=cid)
                pos, orn = p.multiplyTransforms(state[4], state[5], held[1], held[2])
                p.resetBasePositionAndOrientation(body, pos, orn, physicsClientId=cid)
            boxes.append(p.getAABB(body, -1, physicsClientId=cid))
        moving = np.array(boxes)
        spare = float(moving[:, 0, 2].min()) - self._table_top_z - FREE_SPACE_MARGIN_M
        if spare < 0 or not bodies:
            return spare
        apart = np.maximum(0.0, np.maximum(boxes_b[None, :, 0] - moving[:, None, 1],
                                           moving[:, None, 0] - boxes_b[None, :, 1]))
        gap = np.sqrt((apart * apart).sum(axis=2)) - FREE_SPACE_MARGIN_M  # (parts, blocks)
        near = gap < 0
        links = len(self._probe_links)
        for part, k in zip(*np.nonzero(near), strict=True):
            a, link = (arm, self._probe_links[part]) if part < links else (held[0], -1)
            if p.getClosestPoints(a, bodies[k], FREE_SPACE_MARGIN_M, linkIndexA=link,
                                  physicsClientId=cid):
                return -1.0
        return min(spare, float(np.where(near, 0.0, gap).min()))

    def _move_kinematic(self, n: int, q: np.ndarray, v: np.ndarray, held) -> None:
        """n steps without physics: the arm takes its planned state (q, v) and the block it
        holds keeps its place in the grip and rides with it; nothing else moves."""
        self._pb(p.resetJointStatesMultiDof, self.arm, self._arm_idx, [[x] for x in q],
                 [[x] for x in v])
        self._targets[:5], self._target_vel[:5] = q, v
        if held:
            state = self._pb(p.getLinkState, self.arm, self._gripper_link,
                             computeLinkVelocity=1, computeForwardKinematics=1)
            pos, orn = p.multiplyTransforms(state[4], state[5], held[1], held[2])
            lin, w = _riding_velocity(state, pos)
            self._pb(p.resetBasePositionAndOrientation, held[0], pos, orn)
            self._pb(p.resetBaseVelocity, held[0], lin.tolist(), w.tolist())
        self._steps += n
        self.kinematic_steps += n

    def _check_controllers(self, desired: np.ndarray | None = None) -> None:
        pos, vel, _ = self.joint_state()
        traj = self._trajectory
        if traj is not None:
            if traj.check(self.elapsed(traj), pos[:5], ctl.rest(vel[:5]), desired,
                          float(pos[5:].mean())).done:
                self._target_vel[:5] = 0.0
                self._trajectory = None
        grip = self._gripper
        if grip is not None and grip.check(self.elapsed(grip), pos[5:], vel[5:]).done:
            self._gripper = None

    # ------------------------------------------------------------------ sensing
    def arm_in_view(self) -> bool:
        """Whether the camera may see the part of the arm that reaches over the table (every
        link from the forearm out, by its bounding box): the fast sim renders without it only,
        so that no image shows the arm mid-task, where it hides blocks and shifts the pose
        seen of a block it half covers. The parked arm is out of view; the base and upper arm
        stand at the image's edge in every pose and are not counted."""
        key = (self._steps, self._changes)
        if self._in_view is not None and self._in_view[0] == key:
            return self._in_view[1]
        boxes = np.array([self._pb(p.getAABB, self.arm, i) for i in self._reaching_links])
        corners = np.stack([np.where([(c >> k) & 1 for k in range(3)], boxes[:, 1], boxes[:, 0])
                            for c in range(8)], axis=1)  # (links, 8, 3)
        cam = self.camera
        uv = cam.project(corners.reshape(-1, 3)).reshape(len(boxes), 8, 2)
        seen = bool(np.any(
            ~np.isfinite(uv).all(axis=(1, 2))  # a corner behind the camera: may be seen
            | ((uv[..., 0].min(axis=1) <= cam.width - 1) & (uv[..., 0].max(axis=1) >= 0)
               & (uv[..., 1].min(axis=1) <= cam.height - 1) & (uv[..., 1].max(axis=1) >= 0))))
        self._in_view = (key, seen)
        return seen

    def _raw_render(self, width: int, height: int, focal: float) -> tuple[np.ndarray, np.ndarray]:
        cam = self.camera
        fov = math.degrees(2.0 * math.atan(height / 2.0 / focal))
        proj = p.computeProjectionMatrixFOV(fov, width / height, cam.near, cam.far)
        _, _, rgba, depth, _ = self._pb(
            p.getCameraImage, width, height, cam.view_matrix(), proj,
            renderer=p.ER_TINY_RENDERER, flags=p.ER_NO_SEGMENTATION_MASK, shadow=0,
            lightDirection=(0.3, 0.2, 1.0), lightAmbientCoeff=0.6, lightDiffuseCoeff=0.45,
            lightSpecularCoeff=0.0,
        )
        img = np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[:, :, :3]
        return np.ascontiguousarray(img), np.asarray(depth, dtype=np.float32).reshape(height, width)

    def _prepare_table_render(self) -> None:
        """The software renderer spends most of a frame shading the table top, which is flat and
        evenly lit, so its colour is constant: measure it once (table alone in the scene), hide
        the table from the renderer, and paint its projected polygon wherever nothing else was
        drawn. The image is the same; a frame costs several times less."""
        cam = self.camera
        small, _ = self._raw_render(32, 24, cam.focal_px * 32 / cam.width)
        self._table_rgb = np.median(small.reshape(-1, 3), axis=0).astype(np.uint8)
        sx, sy, _ = m.TABLE_SIZE
        cx, cy = m.TABLE_CENTRE_XY
        corners = np.array([[cx + a * sx / 2, cy + b * sy / 2, 0.0]
                            for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
        uv = cam.project(corners)
        self._table_mask: np.ndarray | None = None
        if np.isfinite(uv).all():
            mask = np.zeros((cam.height, cam.width), np.uint8)
            cv2.fillPoly(mask, [np.round(uv).astype(np.int32)], 1)
            self._table_mask = mask.astype(bool)
            self._pb(p.changeVisualShape, self.table, -1, rgbaColor=(0, 0, 0, 0))

    def render(self, fresh: bool = False) -> np.ndarray:
        """The overhead camera image, uint8 (height, width, 3), RGB, read-only.

        A scene that has not moved since the last render (the fast sim between motions:
        physics frozen) gives that image again instead of drawing it anew; `fresh` draws it
        anyway (the render bench)."""
        key = self._scene_key()
        if not fresh and self._rendered is not None and self._rendered[0] == key:
            return self._rendered[1]
        cam = self.camera
        img, depth = self._raw_render(cam.width, cam.height, cam.focal_px)
        if self._table_mask is not None:
            img[(depth >= 0.99999) & self._table_mask] = self._table_rgb
        img.flags.writeable = False
        self._rendered = (key, img)
        return img

    def _scene_key(self) -> tuple:
        """Everything a render shows that can change: the block poses and the arm's joints;
        of an arm out of view (`arm_in_view`), only the joints that move the links before the
        reaching ones (the fingers opening at the park pose change nothing in the image)."""
        poses = tuple(self._pb(p.getBasePositionAndOrientation, body)
                      for body in self.blocks.values())
        joints = tuple(s[0] for s in self._pb(p.getJointStates, self.arm, self._all_idx))
        if not self.arm_in_view():
            joints = joints[:self._joints_before_reaching]
        return tuple(self.blocks), poses, joints

    def ground_truth(self) -> list[BlockState]:
        """True poses, stack levels and visibility of every block."""
        poses = {bid: self._pb(p.getBasePositionAndOrientation, body)
                 for bid, body in self.blocks.items()}
        return block_states(poses, self.cfg.block_size, self.camera)
