"""katana-play on the ROS graph: each topic with its recorded type and the QoS its publishers
offered (a transient-local topic reaches a late joiner), /clock with the recorded times, and a
run's perception detections replayed into a fresh block memory node giving the same
memory/blocks as the original run recorded."""

from __future__ import annotations

import subprocess
import sys
from collections import Counter

import pytest
from katana_bringup.in_process import InProcessGraph
from katana_bringup.play import PlayerNode
from katana_bringup.playback import recorded_messages
from katana_bringup.recorder_node import RecorderNode
from katana_bringup.run import default_params_files, load_params, overrides_for
from katana_common.qos import CLOCK_QOS, EVENT_QOS, STATE_QOS
from katana_common.testing import private_ros_env
from katana_interfaces.msg import Block, BlockArray, Experience
from katana_perception.block_memory_node import BlockMemoryNode
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock


def _record_a_few(path, blocks_published: int = 3) -> None:
    """A recording of memory/blocks (transient local) and curiosity/experience (volatile)."""
    with InProcessGraph() as g:
        rec = RecorderNode(context=g.context, parameter_overrides=[
            Parameter("path", value=str(path)), Parameter("image_rate_hz", value=0.0)])
        g.add(rec)
        pub = g.node("play_test_source")
        blocks = pub.create_publisher(BlockArray, "memory/blocks", STATE_QOS)
        exp = pub.create_publisher(Experience, "curiosity/experience", EVENT_QOS)
        g.wait_for(lambda: blocks.get_subscription_count() and exp.get_subscription_count())
        for i in range(blocks_published):
            blocks.publish(BlockArray(blocks=[Block(id="red", level=i + 1)]))
            exp.publish(Experience(index=i))
        counts = rec.recording.counts
        g.wait_for(lambda: counts.get("/memory/blocks") == blocks_published
                   and counts.get("/curiosity/experience") == blocks_published)
        rec.stop()


def test_topics_are_played_with_their_recorded_type_qos_and_clock(tmp_path):
    path = tmp_path / "run.mcap"
    _record_a_few(path)
    times = [m.log_time_ns for m in recorded_messages(path)]
    with InProcessGraph() as g:
        player = PlayerNode(path, context=g.context)
        g.add(player)
        probe = g.node("play_test_probe")
        clocks: list[int] = []
        probe.create_subscription(
            Clock, "/clock", lambda m: clocks.append(m.clock.sec * 10**9 + m.clock.nanosec),
            CLOCK_QOS)
        g.wait_for(lambda: player.clock_pub.get_subscription_count())
        assert player.play(rate=4.0) == 6
        offered = {t: [i.qos_profile.durability for i in probe.get_publishers_info_by_topic(t)]
                   for t in ("/memory/blocks", "/curiosity/experience")}
        assert offered == {"/memory/blocks": [DurabilityPolicy.TRANSIENT_LOCAL],
                           "/curiosity/experience": [DurabilityPolicy.VOLATILE]}
        assert {n: t for n, t in probe.get_topic_names_and_types()
                if n in offered} == {"/memory/blocks": ["katana_interfaces/msg/BlockArray"],
                                     "/curiosity/experience": ["katana_interfaces/msg/Experience"]}
        late: list[BlockArray] = []  # joins after playback: only a latched topic reaches it
        probe.create_subscription(BlockArray, "memory/blocks", late.append, STATE_QOS)
        g.wait_for(lambda: late)
        assert [b.level for b in late[-1].blocks] == [3]
        g.wait_for(lambda: clocks and clocks[-1] == times[-1])
        assert clocks == sorted(clocks) and times[0] <= clocks[0]


@pytest.mark.timeout(300)
def test_replayed_detections_rebuild_the_recorded_block_memory(tmp_path):
    path = tmp_path / "run.mcap"
    run = subprocess.run(
        [sys.executable, "-m", "katana_bringup.run", "--backend", "sim", "--layers",
         "arm,perception", "--duration", "6", "--record", str(path)],
        env=private_ros_env(), capture_output=True, text=True, timeout=240)
    assert run.returncode == 0, run.stderr[-3000:]
    recorded = [deserialize_message(m.data, BlockArray)
                for m in recorded_messages(path, ["/memory/blocks"])]
    assert len(recorded) >= 5, "the run published too little memory to compare"
    # The memory answers every detection with a memory/blocks stamped as the detection. The
    # recording ends where the recorder stopped: a detection it wrote may have had its answer
    # published after that, so the replay answers it too (the recorder's order of the two
    # topics is not the memory's, hence stamps, not log order).
    detected = [_stamp_ns(deserialize_message(m.data, BlockArray))
                for m in recorded_messages(path, ["/perception/detections"])]
    unanswered = Counter(detected) - Counter(_stamp_ns(b) for b in recorded)
    assert all(t > _stamp_ns(recorded[-1]) for t in unanswered.elements()), \
        "a detection before the recording's end was left unanswered"
    params = load_params(default_params_files("sim"))
    with InProcessGraph() as g:
        memory = BlockMemoryNode(context=g.context,
                                 parameter_overrides=overrides_for("block_memory_node", params))
        player = PlayerNode(path, ["/camera/camera_info", "/perception/detections"],
                            context=g.context)
        g.add(memory, player)
        probe = g.node("replay_probe")
        rebuilt: list[BlockArray] = []
        every = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        probe.create_subscription(BlockArray, "memory/blocks", rebuilt.append, every)
        g.wait_for(lambda: all(p.get_subscription_count() for p in player.pubs.values())
                   and memory.pub.get_subscription_count())
        assert player.play(rate=2.0) == sum(1 for _ in recorded_messages(
            path, ["/camera/camera_info", "/perception/detections"]))
        g.wait_for(lambda: len(rebuilt) >= len(detected), timeout=30.0)
    # same blocks, levels, poses and stamps, message by message, then the cut-off answers
    assert rebuilt[:len(recorded)] == recorded
    assert sorted(_stamp_ns(b) for b in rebuilt[len(recorded):]) == sorted(unanswered.elements())


def _stamp_ns(blocks: BlockArray) -> int:
    return blocks.header.stamp.sec * 10**9 + blocks.header.stamp.nanosec
