"""ExperienceFrames, the one recorder of katana-demo's frames/ and katana-robot's contact sheet:
which camera frame it hands over as the scene before, during and after each experiment."""

from __future__ import annotations

from katana_bringup.frames import ExperienceFrames
from katana_bringup.in_process import InProcessGraph
from katana_common.qos import EVENT_QOS, SENSOR_QOS
from katana_interfaces.action import PickAndPlace
from katana_interfaces.msg import Experience
from sensor_msgs.msg import Image


def _image(value: int) -> Image:
    return Image(width=1, height=1, encoding="rgb8", step=3, data=bytes([value] * 3))


def _value(rgb) -> int | None:
    return None if rgb is None else int(rgb[0, 0, 0])


def test_the_frames_around_each_experiment():
    got = []
    with InProcessGraph(threads=2) as g:
        frames = ExperienceFrames(g.node("frames_under_test"),
                                  lambda msg, f: got.append((msg.index, f)), phases=True)
        pub = g.node("frames_test_publisher")
        images = pub.create_publisher(Image, "camera/image_raw", SENSOR_QOS)
        experiences = pub.create_publisher(Experience, "curiosity/experience", EVENT_QOS)
        feedback = pub.create_publisher(PickAndPlace.Impl.FeedbackMessage,
                                        "pick_and_place/_action/feedback", 10)
        g.wait_for(lambda: all(p.get_subscription_count() for p in
                               (images, experiences, feedback)))

        def image(value: int) -> None:
            images.publish(_image(value))
            g.wait_for(lambda: _value(frames._latest) == value)

        def phase(name: str) -> None:
            msg = PickAndPlace.Impl.FeedbackMessage()
            msg.feedback.phase = name
            feedback.publish(msg)
            g.wait_for(lambda: frames._phase == name)

        def experience(index: int) -> None:
            experiences.publish(Experience(index=index, label=1))
            g.wait_for(lambda: len(got) > index)

        image(1)
        phase("approach")  # the motion starts: the scene it starts from
        image(2)
        phase("lift")  # the first image with the block in the gripper
        image(3)
        image(4)
        phase("release")  # the first image after the release
        image(5)
        experience(0)
        image(6)
        experience(1)  # no motion in between (a dropped attempt's images alone)
    first, second = got[0][1], got[1][1]
    assert [got[0][0], got[1][0]] == [0, 1]
    assert (_value(first.before), _value(first.motion_start), _value(first.pick),
            _value(first.place), _value(first.after)) == (1, 1, 3, 5, 5)
    assert (_value(second.before), _value(second.after)) == (5, 6)
    assert second.motion_start is None and second.pick is None and second.place is None
