"""The curiosity node's outgoing messages, built from core objects (no node state here)."""

from __future__ import annotations

from collections.abc import Mapping

from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point
from katana_common.messages import duration_msg
from katana_interfaces.msg import Experience, FoveaInstance, HeightModel, LearnerState
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from .core.predictors import PredictorBank
from .core.run_record import ExperimentRecord


def experience_msg(record: ExperimentRecord, instance: FoveaInstance, stamp: Time,
                   frame: str) -> Experience:
    msg = Experience()
    msg.header.stamp, msg.header.frame_id = stamp, frame
    msg.index = record.index
    msg.setting = record.setting
    msg.mode = record.mode
    msg.instance = instance
    msg.moved_block = record.moved_block
    msg.label = record.label
    msg.margin_before = record.margin_before
    msg.confidence_before = record.confidence_before
    msg.weights_before = record.weights_before
    msg.weights_after = record.weights_after
    return msg


def learner_state_msg(bank: PredictorBank, modes: Mapping[str, int], strategy: str,
                      max_height: int, stamp: Time, frame: str,
                      all_known_at: int | None = None) -> LearnerState:
    """`modes`: the logged experiments counted by mode (kept as the log grows, so that the
    message costs the same at the thousandth experiment as at the first)."""
    msg = LearnerState()
    msg.header.stamp, msg.header.frame_id = stamp, frame
    msg.experiments = sum(modes.values())
    msg.queries = modes.get("query", 0)
    msg.plans = modes.get("plan", 0)
    msg.strategy = strategy
    msg.alpha = float(bank.rule.alpha)
    msg.theta = float(bank.rule.theta)
    msg.all_known_at = -1 if all_known_at is None else int(all_known_at)
    for h in range(max_height + 1):
        k = bank.slot[h]
        msg.heights.append(HeightModel(
            height=h,
            examples=int(bank.examples[k]),
            weights=[float(v) for v in bank.w[k]],
            margins=[float(v) for v in bank.margin[h]],
            confidence=[float(v) for v in bank.chi[h]],
            unknown=[bool(v) for v in bank.unknown[h]],
        ))
    return msg


def markers_msg(record: ExperimentRecord, instance: FoveaInstance, stamp: Time,
                frame: str) -> MarkerArray:
    """A sphere at the placement (green stable, red fell) and a caption above it."""
    colour = (ColorRGBA(r=0.1, g=0.8, b=0.1, a=0.9) if record.label > 0
              else ColorRGBA(r=0.9, g=0.1, b=0.1, a=0.9))
    place = Marker(ns="placement", id=0, type=Marker.SPHERE, action=Marker.ADD)
    place.header.frame_id, place.header.stamp = frame, stamp
    place.pose = instance.placement
    place.scale.x = place.scale.y = place.scale.z = 0.02
    place.color = colour
    place.lifetime = duration_msg(0.0)
    text = Marker(ns="placement", id=1, type=Marker.TEXT_VIEW_FACING, action=Marker.ADD)
    text.header.frame_id, text.header.stamp = frame, stamp
    p = instance.placement.position
    text.pose.position = Point(x=p.x, y=p.y, z=p.z + 0.05)
    text.scale.z = 0.02
    text.color = colour
    text.text = (f"#{record.index} {record.mode} s={record.state} a={record.action} "
                 f"y={record.label:+d}")
    return MarkerArray(markers=[place, text])
