"""Arbitrary field values in every service request and subscribed message of the perception,
block memory and fovea nodes: each is answered (a service with a reason) or dropped with a log
line, never ends the node, and block memory never publishes a non-finite pose.

The callbacks are called directly with messages built by rclpy's own message classes (so the
field types are those the wire allows); an exception out of a callback is what would end the
node's executor, so here it fails the test. After each input the node still answers a valid
request. Counts of inputs tried and refused are printed at the end (pytest -s).
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest
import rclpy
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from katana_interfaces.msg import Block, BlockArray, Experience, FoveaInstance
from katana_interfaces.srv import FindPlacement, JudgePlacement, ObserveSetting
from katana_perception.block_memory_node import BlockMemoryNode
from katana_perception.core.calibration import Calibration
from katana_perception.core.memory import Block as MemBlock
from katana_perception.core.synthetic import Renderer, stack_block
from katana_perception.fovea_node import FoveaNode
from katana_perception.messages import blocks_to_msg, rgb_to_image
from katana_perception.perception_node import PerceptionNode
from rclpy.context import Context
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header

CALIB = Calibration.overhead_default()
SCENE = [stack_block("red", 0.17, 0.09, 1, 0.2), stack_block("green", 0.26, -0.10, 1, -0.3)]
TALLY: Counter = Counter()
SETTINGS = settings(max_examples=60, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture,
                                           HealthCheck.too_slow])

floats = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                   st.sampled_from([0.0, 0.2, -0.2, 1e12, -1e12, math.nan, math.inf]))
uint8 = st.one_of(st.integers(0, 6), st.integers(0, 255))
names = st.one_of(st.sampled_from(["red", "green", "blue", "", "nobody"]), st.text(max_size=8))


def good_info() -> CameraInfo:
    m = CameraInfo(width=CALIB.width, height=CALIB.height, distortion_model="plumb_bob")
    m.k = CALIB.K.ravel().tolist()
    m.d = [0.0] * 5
    m.r = np.eye(3).ravel().tolist()
    m.p = np.hstack([CALIB.K, np.zeros((3, 1))]).ravel().tolist()
    return m


@st.composite
def camera_infos(draw) -> CameraInfo:
    m = good_info()
    m.width = draw(st.one_of(st.just(CALIB.width), st.integers(0, 2**32 - 1)))
    m.height = draw(st.one_of(st.just(CALIB.height), st.integers(0, 2**32 - 1)))
    m.k = draw(st.one_of(st.just(list(m.k)), st.lists(floats, min_size=9, max_size=9)))
    m.d = draw(st.lists(floats, max_size=16))
    m.p = draw(st.one_of(st.just(list(m.p)), st.lists(floats, min_size=12, max_size=12)))
    m.r = draw(st.one_of(st.just(list(m.r)), st.lists(floats, min_size=9, max_size=9)))
    return m


@st.composite
def images(draw) -> Image:
    w, h = draw(st.integers(0, 40)), draw(st.integers(0, 40))
    enc = draw(st.one_of(st.sampled_from(["rgb8", "bgr8", "rgba8", "mono8", "16UC1", ""]),
                         st.text(max_size=6)))
    step = draw(st.one_of(st.just(w * 3), st.integers(0, 2**32 - 1)))
    data = draw(st.binary(max_size=w * h * 4 + 8))
    return Image(width=w, height=h, encoding=enc, step=step, data=data)


@st.composite
def blocks(draw) -> Block:
    b = Block(id=draw(names), color=draw(names), yaw=draw(floats), level=draw(uint8),
              on_top=draw(st.booleans()), visible=draw(st.booleans()),
              pixel_u=draw(floats), pixel_v=draw(floats), pixel_angle=draw(floats))
    b.pose.position.x, b.pose.position.y, b.pose.position.z = (draw(floats) for _ in range(3))
    q = b.pose.orientation
    q.x, q.y, q.z, q.w = (draw(floats) for _ in range(4))
    b.size.x, b.size.y, b.size.z = (draw(floats) for _ in range(3))
    return b


@st.composite
def block_arrays(draw) -> BlockArray:
    frame = draw(st.sampled_from(["world", "", "camera"]))
    return BlockArray(header=Header(frame_id=frame), blocks=draw(st.lists(blocks(), max_size=5)))


@st.composite
def instances(draw) -> FoveaInstance:
    m = FoveaInstance(state=draw(uint8), action=draw(uint8),
                      features=draw(st.lists(floats, max_size=8)),
                      bits=draw(st.lists(st.booleans(), max_size=6)),
                      pixel_u=draw(floats), pixel_v=draw(floats),
                      support_ids=draw(st.lists(names, max_size=4)))
    p = m.placement
    p.position.x, p.position.y, p.position.z = (draw(floats) for _ in range(3))
    p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = (
        draw(floats) for _ in range(4))
    return m


@pytest.fixture(scope="module")
def ctx():
    context = Context()
    rclpy.init(context=context)
    yield context
    rclpy.try_shutdown(context=context)
    print("\nbad inputs: " + ", ".join(f"{k} {v}" for k, v in sorted(TALLY.items())))


def _tally(kind: str, refused: bool) -> None:
    """One arbitrary input of `kind` tried, and whether the node refused it."""
    TALLY[f"{kind} tried"] += 1
    TALLY[f"{kind} refused"] += refused


def _make(ctx, cls, **params):
    return cls(context=ctx, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])


def _frame(node) -> None:
    rgb = Renderer(CALIB).render(SCENE)[0]
    node.on_image(rgb_to_image(rgb, Header(frame_id="camera_optical_frame")))


class FakePub:
    def __init__(self) -> None:
        self.msgs: list[BlockArray] = []

    def publish(self, msg) -> None:
        self.msgs.append(msg)


def _assert_finite(msgs: list[BlockArray]) -> None:
    for msg in msgs:
        for b in msg.blocks:
            p, q = b.pose.position, b.pose.orientation
            assert all(math.isfinite(v) for v in (p.x, p.y, p.z, q.x, q.y, q.z, q.w, b.yaw)), b


# ---------------------------------------------------------------- perception_node
@pytest.fixture(scope="module")
def perception(ctx):
    node = _make(ctx, PerceptionNode, publish_debug_image=False, blocks_wait_s=0.0)
    node.on_camera_info(good_info())
    _frame(node)
    yield node
    node.destroy_node()


@SETTINGS
@given(info=camera_infos())
def test_perception_camera_info(perception, info):
    before = perception.calibration
    perception.on_camera_info(info)
    taken = perception.calibration is not before
    _tally("camera_info", refused=not taken)
    if taken:
        c = perception.calibration
        assert np.isfinite(c.K).all() and np.isfinite(c.D).all()
    perception.on_camera_info(good_info())


@SETTINGS
@given(img=images())
def test_perception_image(perception, img):
    frames = perception.frames
    perception.on_image(img)
    _tally("image", refused=perception.frames == frames)


@SETTINGS
@given(msg=block_arrays())
def test_perception_memory_blocks(perception, msg):
    perception.on_memory_blocks(msg)
    TALLY["memory/blocks (perception) tried"] += 1


@SETTINGS
@given(phase=uint8, inst=instances(), placed=names, sequence=st.integers(0, 2**64 - 1))
def test_perception_judge_placement(perception, phase, inst, placed, sequence):
    """blocks_wait_s 0: a request naming a memory/blocks not in yet is refused at once (for
    that, or for what is wrong with the rest of it, checked first)."""
    before = JudgePlacement.Request(phase=JudgePlacement.Request.PHASE_BEFORE)
    assert perception.on_judge(before, JudgePlacement.Response()).success
    _frame(perception)
    req = JudgePlacement.Request(phase=phase, instance=inst, placed_block=placed,
                                 blocks_sequence=sequence)
    res = perception.on_judge(req, JudgePlacement.Response())
    TALLY["judge_placement tried"] += 1
    if sequence > perception.blocks_arrivals.number:
        assert not res.success
    if res.success:
        # only a sound request is judged: the phase, a known block and a finite placement
        # within the workspace on a known stack
        p = inst.placement.position
        assert phase in (0, 1)
        if phase == 1:
            assert placed in perception.segmenter.names
            assert all(math.isfinite(v) for v in (p.x, p.y, p.z)) and math.hypot(p.x, p.y) <= 1
            assert inst.state == len(inst.support_ids) and set(inst.support_ids) <= set(
                perception.segmenter.names)
            assert res.label in (-1, 1)
    else:
        TALLY["judge_placement refused"] += 1
        assert res.message and res.label == 0


# ---------------------------------------------------------------- block_memory_node
@pytest.fixture(scope="module")
def memory(ctx):
    node = _make(ctx, BlockMemoryNode)
    node.pub = FakePub()
    node.on_camera_info(good_info())
    yield node
    node.destroy_node()


def _seed_memory(node) -> None:
    node.memory.set_blocks([MemBlock("red", "red", 0.17, 0.09, 0.2),
                            MemBlock("green", "green", 0.26, -0.1, 0.0),
                            MemBlock("blue", "blue", 0.26, -0.1, 0.0, support="green")])


@SETTINGS
@given(msg=block_arrays())
def test_memory_detections(memory, msg):
    _seed_memory(memory)
    memory.pub.msgs.clear()
    memory.on_detections(msg)
    TALLY["detections tried"] += 1
    _assert_finite(memory.pub.msgs)


@SETTINGS
@given(inst=instances(), moved=names, label=st.integers(-128, 127), index=st.integers(0, 2**32 - 1))
def test_memory_experience(memory, inst, moved, label, index):
    _seed_memory(memory)
    memory.pub.msgs.clear()
    memory.on_experience(Experience(instance=inst, moved_block=moved, label=label, index=index))
    _tally("experience", refused=not memory.pub.msgs)
    _assert_finite(memory.pub.msgs)
    assert memory.memory.consistent()


@SETTINGS
@given(info=camera_infos())
def test_memory_camera_info(memory, info):
    memory.on_camera_info(info)
    TALLY["camera_info (memory) tried"] += 1
    c = memory.memory.calibration
    assert np.isfinite(c.K).all() and np.isfinite(c.D).all()
    memory.on_camera_info(good_info())


# ---------------------------------------------------------------- fovea_node
@pytest.fixture(scope="module")
def fovea(ctx):
    node = _make(ctx, FoveaNode, mask_source="image", blocks_wait_s=0.0)
    node.on_camera_info(good_info())
    yield node
    node.destroy_node()


#: the number the memory gave the arrays the fovea tests hold
HELD_SEQUENCE = 5


def _good_blocks() -> BlockArray:
    msg = blocks_to_msg([MemBlock(b.name, b.name, b.x, b.y, b.yaw) for b in SCENE],
                        Header(frame_id="world"))
    msg.sequence = HELD_SEQUENCE
    return msg


def _ready(node) -> None:
    node.on_blocks(_good_blocks())
    node.on_image(rgb_to_image(Renderer(CALIB).render(SCENE)[0], Header()))
    assert node.on_observe(ObserveSetting.Request(max_height=255),
                           ObserveSetting.Response()).success


uint64 = st.one_of(st.integers(0, 2 * HELD_SEQUENCE), st.integers(0, 2**64 - 1))


@SETTINGS
@given(max_height=uint8, blocks_sequence=uint64)
def test_fovea_observe(fovea, max_height, blocks_sequence):
    """Answered from the array held when the request names it or an earlier one; refused,
    naming the array, when it names a later one (blocks_wait_s 0: at once)."""
    _ready(fovea)
    res = fovea.on_observe(ObserveSetting.Request(max_height=max_height,
                                                  blocks_sequence=blocks_sequence),
                           ObserveSetting.Response())
    TALLY["fovea/observe tried"] += 1
    if blocks_sequence > HELD_SEQUENCE:
        assert not res.success and f"number {blocks_sequence} " in res.message
        return
    assert res.success and all(i.state <= max_height for i in res.instances)


@SETTINGS
@given(state=uint8, action=uint8, blocks_sequence=uint64)
def test_fovea_find_placement(fovea, state, action, blocks_sequence):
    _ready(fovea)
    res = fovea.on_find(FindPlacement.Request(state=state, action=action,
                                              blocks_sequence=blocks_sequence),
                        FindPlacement.Response())
    TALLY["fovea/find_placement tried"] += 1
    if blocks_sequence > HELD_SEQUENCE and res.found:
        pytest.fail(f"answered from array {HELD_SEQUENCE} for a request naming {blocks_sequence}")
    if not res.found:
        TALLY["fovea/find_placement refused"] += 1
        assert res.message
    else:
        assert res.instance.state == state and res.instance.action == action
        p = res.instance.placement.position
        assert all(math.isfinite(v) for v in (p.x, p.y, p.z))


@SETTINGS
@given(msg=block_arrays(), info=camera_infos(), img=images())
@pytest.mark.filterwarnings("error::RuntimeWarning")  # a mask drawn from garbage pixels
def test_fovea_topics(fovea, msg, info, img):
    fovea.on_blocks(msg)
    fovea.on_camera_info(info)
    fovea.on_image(img)
    TALLY["fovea topics tried"] += 3
    for state in (0, 1):
        res = fovea.on_find(FindPlacement.Request(state=state, action=1),
                            FindPlacement.Response())
        assert res.found or res.message
        assert not res.message.startswith("internal error"), res.message
    fovea.on_camera_info(good_info())
    _ready(fovea)
