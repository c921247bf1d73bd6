"""The message types a measurement stream may have (:attr:`gpf_nav.estimator.streams.Stream.message`): the
message class and its conversion to a :class:`~gpf_nav.estimator.streams.Reading` in SI. A stream of a
type listed here needs no ROS code of its own."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from geometry_msgs.msg import PoseWithCovarianceStamped, TwistWithCovarianceStamped, Vector3Stamped
from sensor_msgs.msg import Range

from gpf_nav.estimator.streams import Reading
from gpf_nav.ros import conversions as conv


@dataclass(frozen=True)
class MessageType:
    cls: type
    reading: Callable[[object], Reading]


def _vector(msg: Vector3Stamped) -> Reading:
    return Reading(np.array(conv.rae_values(msg)))


def _range(msg: Range) -> Reading:
    return Reading(np.array([float(msg.range)]), limits=(msg.min_range, msg.max_range))


def _pose(msg: PoseWithCovarianceStamped) -> Reading:
    return Reading(*conv.position_fix(msg))


def _twist(msg: TwistWithCovarianceStamped) -> Reading:
    return Reading(*conv.velocity_fix(msg))


MESSAGE_TYPES = {
    "geometry_msgs/Vector3Stamped": MessageType(Vector3Stamped, _vector),
    "sensor_msgs/Range": MessageType(Range, _range),
    "geometry_msgs/PoseWithCovarianceStamped": MessageType(PoseWithCovarianceStamped, _pose),
    "geometry_msgs/TwistWithCovarianceStamped": MessageType(TwistWithCovarianceStamped, _twist),
}
"""``package/Type`` -> class and conversion (values: the vector, the range, the position or the linear
velocity; with the position or linear-velocity covariance block, or the range limits)."""
