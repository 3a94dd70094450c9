"""The three nodes in-process: topics, services, bad input, parameter validation, and the
perception -> memory -> fovea pipeline on rendered images."""

import functools
import itertools
import math
import os
import subprocess
import sys
import time

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from katana_common.executor import MultiThreadedExecutor
from katana_common.params import ParameterError
from katana_common.qos import DIAGNOSTICS_QOS, STATE_QOS
from katana_common.testing import call_service, spin_until
from katana_interfaces.msg import BlockArray, Experience
from katana_interfaces.srv import FindPlacement, JudgePlacement, ObserveSetting
from katana_manipulation.core.pick_place import PickPlaceParams
from katana_manipulation.pick_place_executor import PickPlaceExecutor
from katana_manipulation.testing import place_limit_m
from katana_perception.block_memory_node import BlockMemoryNode
from katana_perception.core.calibration import Calibration
from katana_perception.core.fovea import Instance, feature_vector
from katana_perception.core.memory import Block, BlockMemory
from katana_perception.core.segmentation import Segmenter
from katana_perception.core.synthetic import Renderer, stack_block
from katana_perception.fovea_node import FoveaNode
from katana_perception.messages import (
    blocks_to_msg,
    detection_to_msg,
    instance_to_msg,
    rgb_to_image,
)
from katana_perception.perception_node import PerceptionNode
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header
from visualization_msgs.msg import Marker, MarkerArray

CALIB = Calibration.overhead_default()
_ns = itertools.count()
SCATTER = [stack_block("red", 0.17, 0.09, 1, 0.2), stack_block("green", 0.26, -0.10, 1, -0.3),
           stack_block("blue", 0.18, -0.07, 1, 0.5), stack_block("yellow", 0.27, 0.09, 1, 0.0)]


class Harness:
    """One Context, one executor, a namespace of its own, and a helper node."""

    def __init__(self):
        self.ctx = Context()
        rclpy.init(context=self.ctx)
        self.ns = f"/t{next(_ns)}"
        self.executor = MultiThreadedExecutor(context=self.ctx)
        self.spin_until = functools.partial(spin_until, self.executor, timeout_s=15.0)
        self.nodes = []
        self.helper = self.add(Node("helper", context=self.ctx, namespace=self.ns))
        self.info_pub = self.helper.create_publisher(CameraInfo, "camera/camera_info",
                                                     qos_profile_sensor_data)
        self.image_pub = self.helper.create_publisher(Image, "camera/image_raw",
                                                      qos_profile_sensor_data)
        self.renderer = Renderer(CALIB)
        self.frame = 0

    def add(self, node):
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def make(self, cls, **params):
        overrides = [Parameter(k, value=v) for k, v in params.items()]
        return self.add(cls(context=self.ctx, namespace=self.ns, parameter_overrides=overrides))

    def collect(self, msg_type, topic, qos=10):
        got = []
        self.helper.create_subscription(msg_type, topic, got.append, qos)
        return got

    def camera_info(self):
        m = CameraInfo(width=CALIB.width, height=CALIB.height, distortion_model="plumb_bob")
        m.header.frame_id = "camera_optical_frame"
        m.k = CALIB.K.ravel().tolist()
        m.d = [0.0] * 5
        m.r = np.eye(3).ravel().tolist()
        m.p = np.hstack([CALIB.K, np.zeros((3, 1))]).ravel().tolist()
        self.info_pub.publish(m)

    def image(self, scene, encoding="rgb8"):
        self.frame += 1
        rgb, _ = self.renderer.render(scene, seed=self.frame)
        msg = rgb_to_image(rgb, Header(frame_id="camera_optical_frame"))
        msg.header.stamp.sec = self.frame
        if encoding == "bgr8":
            msg.encoding = "bgr8"
            msg.data = np.ascontiguousarray(rgb[:, :, ::-1]).tobytes()
        self.image_pub.publish(msg)

    def call(self, cli, req):
        return call_service(self.executor, cli, req, timeout_s=15.0)

    def close(self):
        for n in self.nodes:
            self.executor.remove_node(n)
            n.destroy_node()
        self.executor.shutdown()
        rclpy.shutdown(context=self.ctx)


@pytest.fixture
def ros():
    h = Harness()
    yield h
    h.close()


def by_id(msg):
    return {b.id: b for b in msg.blocks}


def test_perception_node_publishes_detections_and_survives_bad_images(ros):
    ros.make(PerceptionNode)
    dets = ros.collect(BlockArray, "perception/detections")
    assert ros.spin_until(lambda: ros.image_pub.get_subscription_count() > 0)

    def feed_until(publish, cond):  # sensor-data QoS may drop: publish until it arrives
        for _ in range(50):
            publish()
            if ros.spin_until(cond, timeout_s=0.3):
                return True
        return False

    # Malformed images: wrong byte count, unknown encoding; nothing comes out, no crash.
    bad = Image(height=480, width=640, encoding="rgb8", step=1920, data=bytes(100))
    weird = Image(height=2, width=2, encoding="mono16", step=4, data=bytes(8))
    ros.camera_info()
    for _ in range(5):
        ros.image_pub.publish(bad)
        ros.image_pub.publish(weird)
        ros.spin_until(lambda: False, timeout_s=0.05)
    assert dets == []
    assert feed_until(lambda: (ros.camera_info(), ros.image(SCATTER, "bgr8")), lambda: dets)
    got = by_id(dets[-1])
    assert set(got) == {"red", "green", "blue", "yellow"}
    assert dets[-1].header.frame_id == "world"
    for b in SCATTER:
        p = got[b.name].pose.position
        assert math.hypot(p.x - b.x, p.y - b.y) < 0.005
        assert got[b.name].on_top and got[b.name].visible and got[b.name].level == 1


def test_perception_node_reports_the_camera_on_diagnostics(ros):
    """WARN before the first image; then OK with as many images received as the node took."""
    node = ros.make(PerceptionNode)
    statuses = ros.collect(DiagnosticArray, "/diagnostics", DIAGNOSTICS_QOS)
    assert ros.spin_until(lambda: statuses)
    first = statuses[-1].status[0]
    assert first.name == "perception_node: camera" and first.level == b"\x01"
    assert first.message == "no images yet"
    assert ros.spin_until(lambda: ros.image_pub.get_subscription_count() > 0)
    ros.camera_info()
    for _ in range(3):
        ros.image(SCATTER)
        ros.spin_until(lambda: False, timeout_s=0.05)
    assert ros.spin_until(lambda: node.images.count >= 1)
    count = len(statuses)
    assert ros.spin_until(lambda: len(statuses) > count, timeout_s=3.0)
    status = statuses[-1].status[0]
    values = {kv.key: kv.value for kv in status.values}
    assert values["received"] == str(node.images.count)
    assert status.level == b"\x00" or "no images for" in status.message


def red_on_green_instance():
    return instance_to_msg(Instance(
        state=1, action=6, bits=(True,) * 5, features=feature_vector(6), u=0.0, v=0.0,
        angle=0.0, x=0.262, y=-0.098, z=0.045, yaw=-0.3, support_ids=("green",)))


def _show(ros, node, scene) -> None:
    """Camera info and an image of `scene` until the perception node has taken the image."""
    n = node.frames
    for _ in range(50):
        ros.camera_info()
        ros.image(scene)
        if ros.spin_until(lambda: node.frames > n, timeout_s=0.3):
            return
    raise AssertionError("image never arrived")


def test_judge_placement_service(ros):
    node = ros.make(PerceptionNode)
    cli = ros.helper.create_client(JudgePlacement, "perception/judge_placement")
    before = JudgePlacement.Request(phase=JudgePlacement.Request.PHASE_BEFORE)
    after = JudgePlacement.Request(phase=JudgePlacement.Request.PHASE_AFTER, placed_block="red",
                                   instance=red_on_green_instance())
    res = ros.call(cli, after)
    assert not res.success and "no image" in res.message

    _show(ros, node, SCATTER)
    res = ros.call(cli, after)
    assert not res.success and "PHASE_BEFORE" in res.message
    res = ros.call(cli, before)
    assert res.success and res.label == 0
    res = ros.call(cli, after)
    assert not res.success and "no new image" in res.message
    for name, req in (("ghost", JudgePlacement.Request(phase=1, placed_block="ghost",
                                                        instance=red_on_green_instance())),
                      ("phase", JudgePlacement.Request(phase=7))):
        res = ros.call(cli, req)
        assert not res.success and ("not in the colour table" if name == "ghost"
                                    else "unknown phase") in res.message
    # red put on green: stable
    stacked = [b for b in SCATTER if b.name != "red"] + [stack_block("red", 0.262, -0.098, 2,
                                                                       -0.3)]
    _show(ros, node, stacked)
    res = ros.call(cli, after)
    assert res.success and res.label == 1, res.message
    res = ros.call(cli, after)  # the before snapshot was used up
    assert not res.success and "PHASE_BEFORE" in res.message
    # red put on green but slid off onto the table: fell
    _show(ros, node, SCATTER)
    assert ros.call(cli, before).success
    slid = [b for b in SCATTER if b.name != "red"] + [stack_block("red", 0.21, -0.13, 1, 0.1)]
    _show(ros, node, slid)
    res = ros.call(cli, after)
    assert res.success and res.label == -1 and "mm from the placement" in res.message


def test_the_judge_keeps_the_memory_blocks_the_request_names(ros):
    """The learner asks for a judgement on the memory it acted on: the perception's own
    subscription may not have taken that array in yet. PHASE_BEFORE naming array 2 while the
    node holds array 1 is answered only once array 2 is in, and keeps it; one naming an array
    that never comes is refused after blocks_wait_s, saying so."""
    node = ros.make(PerceptionNode, blocks_wait_s=10.0)
    cli = ros.helper.create_client(JudgePlacement, "perception/judge_placement")
    pub = ros.helper.create_publisher(BlockArray, "memory/blocks", STATE_QOS)
    _show(ros, node, SCATTER)
    first = blocks_msg([Block("red", "red", 0.18, 0.08, 0.3)])
    first.sequence = 1
    pub.publish(first)
    assert ros.spin_until(lambda: node.blocks_arrivals.number == 1)
    before = JudgePlacement.Request(phase=JudgePlacement.Request.PHASE_BEFORE, blocks_sequence=2)
    future = cli.call_async(before)
    assert not ros.spin_until(future.done, timeout_s=0.5)  # array 2 is not in: no answer yet
    second = blocks_msg([Block("red", "red", 0.18, 0.08, 0.3),
                         Block("green", "green", 0.22, -0.08, -0.2)])
    second.sequence = 2
    pub.publish(second)
    assert ros.spin_until(future.done)
    assert future.result().success
    assert set(node.before[0].blocks) == {"red", "green"}  # array 2's blocks, kept
    node.set_parameters([Parameter("blocks_wait_s", value=0.2)])
    start = time.monotonic()
    before.blocks_sequence = 9
    res = ros.call(cli, before)
    assert not res.success and time.monotonic() - start >= 0.2
    assert "number 9" in res.message and "blocks_wait_s" in res.message


def test_camera_info_and_memory_are_taken_while_images_keep_the_node_busy(ros, monkeypatch):
    """A camera faster than segmentation keeps the image subscription ready all the time: the
    node still calibrates and takes memory/blocks in (before, in one group with the images,
    it lost every race for the group and never calibrated)."""
    original = PerceptionNode.on_image

    def slow(self, msg):
        time.sleep(0.05)  # slower than the images below come
        original(self, msg)

    monkeypatch.setattr(PerceptionNode, "on_image", slow)
    node = ros.make(PerceptionNode)
    pub = ros.helper.create_publisher(BlockArray, "memory/blocks", STATE_QOS)
    assert ros.spin_until(lambda: ros.image_pub.get_subscription_count() > 0)
    memory = blocks_msg([Block("red", "red", 0.18, 0.08, 0.3)])
    memory.sequence = 4
    start = time.monotonic()
    while time.monotonic() - start < 10.0 and not (
            node.calibration is not None and node.blocks_arrivals.number == 4):
        ros.image(SCATTER)  # every 10 ms, five times faster than the node takes them
        ros.camera_info()
        pub.publish(memory)
        ros.spin_until(lambda: False, timeout_s=0.01)
    assert node.calibration is not None and node.blocks_arrivals.number == 4
    ros.spin_until(lambda: False, timeout_s=0.3)  # the images still queued are taken


def detections_msg(scene, levels=None):
    rgb, _ = Renderer(CALIB).render(scene)
    dets = Segmenter().segment(rgb, CALIB, levels)
    return BlockArray(header=Header(frame_id="world"),
                      blocks=[detection_to_msg(d, CALIB) for d in dets])


def test_block_memory_draws_each_remembered_block_as_a_box(ros):
    """memory/markers (for RViz and Foxglove) holds, after a delete-all, one box per block of
    memory/blocks at its pose and size in the world frame, and its id above it."""
    ros.make(BlockMemoryNode)
    pub = ros.helper.create_publisher(BlockArray, "perception/detections", 10)
    world = ros.collect(BlockArray, "memory/blocks", STATE_QOS)
    markers = ros.collect(MarkerArray, "memory/markers", STATE_QOS)
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0)
    scatter = detections_msg(SCATTER)
    for _ in range(50):
        ros.camera_info()
        pub.publish(scatter)
        if ros.spin_until(lambda: world and markers, timeout_s=0.3):
            break
    assert ros.spin_until(lambda: len(markers) >= len(world))
    blocks, drawn = world[-1].blocks, markers[-1].markers
    assert drawn[0].action == Marker.DELETEALL
    boxes = [m for m in drawn if m.type == Marker.CUBE]
    labels = {m.text: m for m in drawn if m.type == Marker.TEXT_VIEW_FACING}
    assert len(boxes) == len(blocks) == 4
    for box, block in zip(boxes, blocks, strict=True):
        assert box.header.frame_id == "world" and box.pose == block.pose
        assert (box.scale.x, box.scale.y, box.scale.z) == (
            block.size.x, block.size.y, block.size.z)
        assert labels[block.id].pose.position.z > block.pose.position.z
    assert len({m.id for m in drawn[1:]}) == len(drawn) - 1


def test_block_memory_node(ros):
    ros.make(BlockMemoryNode)
    pub = ros.helper.create_publisher(BlockArray, "perception/detections", 10)
    exp_pub = ros.helper.create_publisher(Experience, "curiosity/experience", 10)
    world = ros.collect(BlockArray, "memory/blocks", STATE_QOS)
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0)
    ros.camera_info()
    scatter = detections_msg(SCATTER)
    for _ in range(50):
        ros.camera_info()
        pub.publish(scatter)
        if ros.spin_until(lambda: world, timeout_s=0.3):
            break
    got = by_id(world[-1])
    assert set(got) == {"red", "green", "blue", "yellow"}
    assert all(b.level == 1 and b.on_top and b.visible for b in got.values())
    # red onto green: the detections show red over green, green hidden.
    stacked = [b for b in SCATTER if b.name != "red"] + [stack_block("red", 0.263, -0.1, 2, -0.3)]
    msg = detections_msg(stacked, {"green": 1, "red": 2})
    # A broken entry is skipped, the rest is used.
    broken = BlockArray(header=msg.header, blocks=list(msg.blocks))
    junk = type(msg.blocks[0])(id="purple", color="purple", pixel_u=math.nan)
    broken.blocks.append(junk)
    n = len(world)
    pub.publish(broken)
    assert ros.spin_until(lambda: len(world) > n)
    exp = Experience(label=1, moved_block="red")
    exp.instance.state = 1
    exp.instance.support_ids = ["green"]
    exp.instance.placement.position.x, exp.instance.placement.position.y = 0.263, -0.1
    n = len(world)
    exp_pub.publish(exp)
    assert ros.spin_until(lambda: len(world) > n)
    got = by_id(world[-1])
    assert "purple" not in got
    assert got["red"].level == 2 and not got["green"].on_top and not got["green"].visible
    assert abs(got["red"].pose.position.z - 0.045) < 1e-9
    # a late subscriber still gets the state (transient local)
    late = []
    ros.helper.create_subscription(BlockArray, "memory/blocks", late.append, STATE_QOS)
    assert ros.spin_until(lambda: late)
    assert by_id(late[-1])["red"].level == 2
    # an experience with a nonsense label changes nothing
    n = len(world)
    exp_pub.publish(Experience(label=0, moved_block="red"))
    ros.spin_until(lambda: len(world) > n, timeout_s=0.5)
    assert len(world) == n


def test_block_memory_numbers_its_arrays_with_the_last_experience(ros):
    """The learner's exact ordering: memory/blocks names the last experience handled, its levels
    version and the settled frames after the experience (located on the current levels, changing
    none); a frame located on the levels from before that experience (perception echoes the
    experience its levels came from) is skipped."""
    ros.make(BlockMemoryNode)
    pub = ros.helper.create_publisher(BlockArray, "perception/detections", 10)
    exp_pub = ros.helper.create_publisher(Experience, "curiosity/experience", 10)
    world = ros.collect(BlockArray, "memory/blocks", STATE_QOS)
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0)
    scatter = detections_msg(SCATTER)
    for _ in range(50):
        ros.camera_info()
        pub.publish(scatter)
        if ros.spin_until(lambda: world, timeout_s=0.3):
            break
    assert (world[-1].experience, world[-1].settled_frames) == (-1, 0)  # the levels are new
    exp = Experience(label=1, moved_block="red", index=7)
    exp.instance.state = 1
    exp.instance.support_ids = ["green"]
    exp.instance.placement.position.x, exp.instance.placement.position.y = 0.263, -0.1
    n = len(world)
    exp_pub.publish(exp)
    assert ros.spin_until(lambda: len(world) > n)
    assert (world[-1].experience, world[-1].settled_frames) == (7, 0)
    version = world[-1].levels_version
    assert by_id(world[-1])["red"].level == 2
    stale = detections_msg(SCATTER)  # segmented on the levels before experience 7
    stale.experience = 6
    n = len(world)
    pub.publish(stale)
    ros.spin_until(lambda: len(world) > n, timeout_s=0.5)
    assert len(world) == n  # skipped: red stays where the experience put it
    stacked = [b for b in SCATTER if b.name != "red"] + [stack_block("red", 0.263, -0.1, 2, -0.3)]
    fresh = detections_msg(stacked, {"green": 1, "red": 2})
    fresh.experience, fresh.levels_version = 7, version
    for frames in (1, 2):  # located on the levels the experience left, changing none: settled
        pub.publish(fresh)
        assert ros.spin_until(lambda before=n: len(world) > before)
        n = len(world)
        assert (world[-1].experience, world[-1].settled_frames) == (7, frames)
        assert world[-1].levels_version == version
    # every array published is numbered one past the one before (the fovea's ordering)
    assert [m.sequence for m in world] == list(range(1, len(world) + 1))
    fresh.levels_version = version - 1  # on other levels: folded, not counted as settled
    pub.publish(fresh)
    assert ros.spin_until(lambda before=n: len(world) > before)
    assert world[-1].settled_frames == 2
    assert by_id(world[-1])["red"].level == 2


def blocks_msg(blocks):
    m = BlockMemory(CALIB)
    m.set_blocks(blocks)
    return blocks_to_msg(m.snapshot(), Header(frame_id="world"))


def test_fovea_node_services(ros):
    ros.make(FoveaNode)
    observe = ros.helper.create_client(ObserveSetting, "fovea/observe")
    find = ros.helper.create_client(FindPlacement, "fovea/find_placement")
    res = ros.call(observe, ObserveSetting.Request(max_height=255))
    assert not res.success and "memory/blocks" in res.message
    pub = ros.helper.create_publisher(BlockArray, "memory/blocks", STATE_QOS)
    pub.publish(blocks_msg([Block("red", "red", 0.18, 0.08, 0.3),
                            # within the 0.25 m reach for placing on a stack of two
                            Block("green", "green", 0.22, -0.08, -0.2),
                            Block("blue", "blue", 0.22, -0.08, -0.1, support="green"),
                            Block("yellow", "yellow", 0.20, 0.0, 0.5)]))
    ros.camera_info()
    for _ in range(50):
        res = ros.call(observe, ObserveSetting.Request(max_height=255))
        if res.success:
            break
        ros.camera_info()
    assert res.success, res.message
    states = [i.state for i in res.instances]
    assert states[0] == 0 and states == sorted(states) and set(states) == {0, 1, 2}
    for i in res.instances:
        assert len(i.features) == 7 and i.features[i.action - 1] == 1.0 and len(i.bits) == 5
        assert len(i.support_ids) == i.state
    low = ros.call(observe, ObserveSetting.Request(max_height=1))
    assert {i.state for i in low.instances} == {0, 1} and low.setting == res.setting
    bad = ros.call(find, FindPlacement.Request(state=5, action=1))
    assert not bad.found and "height 5" in bad.message
    bad = ros.call(find, FindPlacement.Request(state=2, action=9))
    assert not bad.found and "action 9" in bad.message
    ok = ros.call(find, FindPlacement.Request(state=2, action=6))
    assert ok.found and list(ok.instance.support_ids) == ["green", "blue"]
    assert ok.instance.placement.position.z == pytest.approx(0.075)


def test_fovea_answers_from_the_memory_blocks_the_request_names(ros):
    """The learner waits for a memory/blocks and asks the fovea about it: the fovea's own
    subscription may not have taken that array in yet. A request naming array 2 while the fovea
    holds array 1 is answered only once array 2 is in, and from it; one naming an array that
    never comes is refused after blocks_wait_s, saying so."""
    fovea = ros.make(FoveaNode, blocks_wait_s=10.0)
    observe = ros.helper.create_client(ObserveSetting, "fovea/observe")
    pub = ros.helper.create_publisher(BlockArray, "memory/blocks", STATE_QOS)
    loose = blocks_msg([Block("red", "red", 0.18, 0.08, 0.3),
                        Block("green", "green", 0.22, -0.08, -0.2)])
    loose.sequence = 1
    pub.publish(loose)
    ros.camera_info()
    for _ in range(50):
        res = ros.call(observe, ObserveSetting.Request(max_height=255, blocks_sequence=1))
        if res.success:
            break
        ros.camera_info()
    assert res.success and {i.state for i in res.instances} == {0, 1}
    future = observe.call_async(ObserveSetting.Request(max_height=255, blocks_sequence=2))
    assert not ros.spin_until(future.done, timeout_s=0.5)  # array 2 is not in: no answer yet
    stacked = blocks_msg([Block("red", "red", 0.18, 0.08, 0.3),
                          Block("green", "green", 0.22, -0.08, -0.2),
                          Block("blue", "blue", 0.22, -0.08, -0.1, support="green")])
    stacked.sequence = 2
    pub.publish(stacked)
    assert ros.spin_until(future.done)
    res = future.result()
    assert res.success and {i.state for i in res.instances} == {0, 1, 2}
    fovea.set_parameters([Parameter("blocks_wait_s", value=0.2)])
    start = time.monotonic()
    res = ros.call(observe, ObserveSetting.Request(max_height=255, blocks_sequence=9))
    assert not res.success and time.monotonic() - start >= 0.2
    assert "number 9" in res.message and "blocks_wait_s" in res.message
    find = ros.helper.create_client(FindPlacement, "fovea/find_placement")
    res = ros.call(find, FindPlacement.Request(state=2, action=6, blocks_sequence=9))
    assert not res.found and "number 9" in res.message
    ok = ros.call(find, FindPlacement.Request(state=2, action=6, blocks_sequence=2))
    assert ok.found and list(ok.instance.support_ids) == ["green", "blue"]


def test_pipeline_image_to_instances(ros):
    ros.make(PerceptionNode)
    ros.make(BlockMemoryNode)
    fovea = ros.make(FoveaNode)
    world = ros.collect(BlockArray, "memory/blocks", STATE_QOS)
    observe = ros.helper.create_client(ObserveSetting, "fovea/observe")
    scene = SCATTER[1:] + [stack_block("red", 0.185, -0.068, 2, 0.45)]  # red on blue
    blocks_seen = lambda: world and len(world[-1].blocks) == 4  # noqa: E731
    for _ in range(80):
        ros.camera_info()
        ros.image(SCATTER)
        if ros.spin_until(blocks_seen, timeout_s=0.3):
            break
    assert blocks_seen()
    # red is picked and put on blue (no experience message: the memory infers it)
    for _ in range(80):
        ros.camera_info()
        ros.image(scene)
        if ros.spin_until(lambda: by_id(world[-1])["red"].level == 2, timeout_s=0.3):
            break
    got = by_id(world[-1])
    assert got["red"].level == 2 and not got["blue"].on_top
    # the fovea hears memory/blocks on its own executor thread: it answers from what it has
    # heard, so wait until it has heard the stack (the collector above may hear it first)
    assert ros.spin_until(lambda: fovea.blocks is not None and any(
        b.id == "red" and b.level == 2 for b in fovea.blocks))
    res = ros.call(observe, ObserveSetting.Request(max_height=255))
    assert res.success and {i.state for i in res.instances} == {0, 1, 2}
    assert any(list(i.support_ids) == ["blue", "red"] for i in res.instances)


@pytest.mark.parametrize("cls,params,name", [
    (PerceptionNode, {"saturation_min": 300}, "saturation_min"),
    (PerceptionNode, {"color_table": ["red:0-7", "red:170-179"]}, "color_table"),
    (PerceptionNode, {"camera_position": [0.2, 0.0]}, "camera_position"),
    (PerceptionNode, {"extrinsics_file": "/nonexistent.yaml"}, "extrinsics_file"),
    (BlockMemoryNode, {"position_tolerance": -1.0}, "position_tolerance"),
    (BlockMemoryNode, {"block_size": [0.04, 0.04, 5.0]}, "block_size"),
    (FoveaNode, {"point_offset_px": 30.0}, "offset_px"),
    (FoveaNode, {"mask_source": "dreams"}, "mask_source"),
    (FoveaNode, {"max_height": "three"}, "max_height"),
])
def test_invalid_parameters_stop_the_node_naming_them(ros, cls, params, name):
    with pytest.raises(ParameterError, match=name):
        ros.make(cls, **params)


@pytest.mark.parametrize("module,param", [
    ("katana_perception.perception_node", "value_min:=-5"),
    ("katana_perception.block_memory_node", "cover_fraction:=7.0"),
    ("katana_perception.fovea_node", "fovea_size_px:=1"),
])
def test_main_exits_2_naming_the_parameter(module, param):
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="OFF")
    proc = subprocess.run([sys.executable, "-m", module, "--ros-args", "-p", param],
                          capture_output=True, text=True, timeout=60, env=env)
    assert proc.returncode == 2  # katana_common.node_runner: an invalid configuration
    assert param.split(":=")[0] in proc.stderr + proc.stdout


def test_fovea_node_with_image_masks(ros):
    ros.make(FoveaNode, mask_source="image")
    observe = ros.helper.create_client(ObserveSetting, "fovea/observe")
    pub = ros.helper.create_publisher(BlockArray, "memory/blocks", STATE_QOS)
    pub.publish(blocks_msg([Block(b.name, b.name, b.x, b.y, b.yaw) for b in SCATTER]))
    res = ros.call(observe, ObserveSetting.Request(max_height=255))
    assert not res.success
    for _ in range(50):
        ros.camera_info()
        ros.image(SCATTER)
        res = ros.call(observe, ObserveSetting.Request(max_height=255))
        if res.success:
            break
    assert res.success, res.message
    assert {i.state for i in res.instances} == {0, 1}
    assert {tuple(i.support_ids) for i in res.instances if i.state} == {
        (b.name,) for b in SCATTER}



def test_fovea_node_offers_placements_within_the_executors_reach():
    """grasp_offset given to every node (as graph.yaml's `/**` gives it) moves the fovea's
    placement reach with the executor's: on every stack height the far edge lies where the
    executor's planner, with that geometry, stops finding a plan (from its kinematics, without
    core.reach), and on a stack of three well beyond the default geometry's."""
    shared = [Parameter("grasp_offset", value=-0.015)]  # a lower grip: a taller stack reachable
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        fovea = FoveaNode(context=ctx, parameter_overrides=shared)
        executor = PickPlaceExecutor(context=ctx, parameter_overrides=shared)
        bands = fovea.fovea.reach_by_height
        assert len(bands) == fovea.fovea.max_height + 1
        for height, (near, far) in enumerate(bands):
            limit = place_limit_m(executor.planner.p, height, inside=0.5 * (near + far))
            assert limit - 0.01 <= far <= limit, height
        assert bands[3][1] > place_limit_m(PickPlaceParams(), 3, inside=0.15) + 0.02
        fovea.destroy_node()
        executor.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


def test_live_parameters_apply_and_read_only_ones_are_refused(ros):
    """Through the SetParameters service `ros2 param set` calls."""
    perception = ros.make(PerceptionNode)
    memory = ros.make(BlockMemoryNode)
    fovea = ros.make(FoveaNode)

    def set_param(node, name, value):
        client = ros.helper.create_client(SetParameters, f"{ros.ns}/{node}/set_parameters")
        kind = (ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=value)
                if isinstance(value, int) and not isinstance(value, bool) else
                ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value)
                if isinstance(value, float) else
                ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value))
        req = SetParameters.Request(parameters=[ParameterMsg(name=name, value=kind)])
        return ros.call(client, req).results[0]

    ok = set_param("perception_node", "saturation_min", 100)
    assert ok.successful and perception.segmenter.s_min == 100
    ok = set_param("perception_node", "position_tolerance", 0.02)
    assert ok.successful and perception.judge_params.position_tolerance == 0.02
    bad = set_param("perception_node", "saturation_min", 300)
    assert not bad.successful and "saturation_min" in bad.reason
    assert perception.segmenter.s_min == 100  # the old value is kept
    ro = set_param("perception_node", "color_table", "red:0-7")
    assert not ro.successful
    ok = set_param("block_memory_node", "cover_fraction", 0.5)
    assert ok.successful and memory.memory_params.cover_fraction == 0.5
    for name, value in (("mask_source", "image"), ("max_height", 2), ("camera_position", 0.3)):
        ro = set_param("fovea_node", name, value)
        assert not ro.successful, name
    assert fovea.mask_source == "memory" and fovea.fovea.max_height == 3


def test_a_repeated_frame_gives_the_same_blocks_without_segmenting_it_again(ros):
    node = ros.make(PerceptionNode)
    calls = []
    segment = node.segmenter.segment
    node.segmenter.segment = lambda *a: calls.append(a[2].copy()) or segment(*a)
    dets = ros.collect(BlockArray, "perception/detections")
    memory_pub = ros.helper.create_publisher(BlockArray, "memory/blocks", STATE_QOS)
    assert ros.spin_until(lambda: ros.image_pub.get_subscription_count() > 0)
    rgb, _ = ros.renderer.render(SCATTER, seed=1)

    def frame(sec: int) -> None:  # the same pixels under a new stamp; sensor QoS may drop one
        msg = rgb_to_image(rgb, Header(frame_id="camera_optical_frame"))
        msg.header.stamp.sec = sec
        for _ in range(50):
            ros.camera_info()
            ros.image_pub.publish(msg)
            if ros.spin_until(lambda: dets and dets[-1].header.stamp.sec == sec, timeout_s=0.3):
                return
        raise AssertionError(f"no detections for the frame stamped {sec}")

    frame(1)
    frame(2)
    assert len(calls) == 1  # the second frame was the first one again
    assert [b.id for b in dets[-1].blocks] == [b.id for b in dets[0].blocks]
    assert [b.pose for b in dets[-1].blocks] == [b.pose for b in dets[0].blocks]
    # the memory says red sits on a block now: the same pixels mean something else
    memory = BlockArray(header=Header(frame_id="world"), blocks=[
        b for b in dets[-1].blocks])
    memory.blocks[0].level = 2
    memory_pub.publish(memory)
    assert ros.spin_until(lambda: node.levels.get(memory.blocks[0].id) == 2)
    frame(3)
    assert len(calls) == 2 and calls[-1][memory.blocks[0].id] == 2
    frame(4)
    assert len(calls) == 2


def test_new_levels_after_an_experience_segment_the_latest_image_again_at_once(ros):
    """The memory folds an experience in and publishes its new levels: perception answers with
    detections of its latest image located on them, stamped with that image and numbered with
    the experience and levels version, without waiting for the next image."""
    node = ros.make(PerceptionNode)
    calls = []
    segment = node.segmenter.segment
    node.segmenter.segment = lambda *a: calls.append(a[2].copy()) or segment(*a)
    dets = ros.collect(BlockArray, "perception/detections")
    memory_pub = ros.helper.create_publisher(BlockArray, "memory/blocks", STATE_QOS)
    assert ros.spin_until(lambda: ros.image_pub.get_subscription_count() > 0)
    rgb, _ = ros.renderer.render(SCATTER, seed=1)
    msg = rgb_to_image(rgb, Header(frame_id="camera_optical_frame"))
    msg.header.stamp.sec = 5
    for _ in range(50):
        ros.camera_info()
        ros.image_pub.publish(msg)
        if ros.spin_until(lambda: dets, timeout_s=0.3):
            break
    assert dets[-1].experience == -1 and len(calls) == 1
    memory = BlockArray(header=Header(frame_id="world"), blocks=list(dets[-1].blocks),
                        experience=3, levels_version=4)
    memory.blocks[0].level = 2
    n = len(dets)
    memory_pub.publish(memory)
    assert ros.spin_until(lambda: len(dets) > n)
    assert (dets[-1].experience, dets[-1].levels_version) == (3, 4)
    assert dets[-1].header.stamp.sec == 5
    assert len(calls) == 2 and calls[-1][memory.blocks[0].id] == 2
    # the same levels version again (the memory answers every frame): nothing more
    n = len(dets)
    memory_pub.publish(memory)
    ros.spin_until(lambda: len(dets) > n, timeout_s=0.5)
    assert len(dets) == n
