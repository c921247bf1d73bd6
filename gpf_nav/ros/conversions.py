"""Message <-> numpy conversions for the ROS nodes (message types only; no rclpy node machinery).

Conventions (also in ``docs/ros.md``):

* Times are integer nanoseconds of ROS time (``sec * 1e9 + nanosec``) inside the nodes.
* The world frame is the model's frame (Moon-centred inertial for the lunar model), state
  ``[x, y, z, vx, vy, vz]`` in m and m/s.
* Odometry: pose orientation is the identity quaternion (the filter has no attitude) and the rotation
  blocks of both 6x6 covariances are :data:`UNKNOWN_ROTATION_VARIANCE` on the diagonal, zero
  elsewhere. The twist is expressed in *world-frame axes* (the child frame's axes are taken aligned
  with the world's), not rotated into a body frame as REP 105 would have it.
"""
from __future__ import annotations

import math

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Pose, PoseArray, TransformStamped, Vector3Stamped
from nav_msgs.msg import Odometry

UNKNOWN_ROTATION_VARIANCE = 1e6
"""rad^2: variance written on the diagonal of the rotation blocks of published covariances."""


# --- time --------------------------------------------------------------------------------------------
def stamp_to_ns(stamp) -> int:
    """``builtin_interfaces/Time`` -> integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def ns_to_stamp(ns: int) -> Time:
    """Integer nanoseconds (>= 0) -> ``builtin_interfaces/Time``."""
    ns = int(ns)
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def seconds_to_ns(t: float) -> int:
    """Seconds -> integer nanoseconds, rounded."""
    return int(round(float(t) * 1e9))


# --- rotations ---------------------------------------------------------------------------------------
def quaternion_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    """Rotation matrix ``(3, 3)`` of the (normalised) quaternion ``(x, y, z, w)``: body -> world."""
    n = math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def matrix_quaternion(R: np.ndarray) -> tuple[float, float, float, float]:
    """The unit quaternion ``(x, y, z, w)`` of a rotation matrix ``(3, 3)`` (inverse of
    :func:`quaternion_matrix`; Shepperd's choice of the largest component keeps it accurate)."""
    m = np.asarray(R, dtype=float)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    k = int(np.argmax([trace, m[0, 0], m[1, 1], m[2, 2]]))
    if k == 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4
    elif k == 1:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s
    elif k == 2:
        s = 2.0 * math.sqrt(1.0 - m[0, 0] + m[1, 1] - m[2, 2])
        q = (m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s
    else:
        s = 2.0 * math.sqrt(1.0 - m[0, 0] - m[1, 1] + m[2, 2])
        q = (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s
    return tuple(float(v) for v in q)


def transform_msg(parent: str, child: str, stamp_ns: int, translation: np.ndarray,
                  R: np.ndarray) -> TransformStamped:
    """``geometry_msgs/TransformStamped`` ``parent -> child``: the child's coordinates ``c`` are
    ``translation (3,) + R (3, 3) c`` in the parent's."""
    msg = TransformStamped()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id, msg.child_frame_id = parent, child
    t = msg.transform.translation
    t.x, t.y, t.z = (float(v) for v in translation)
    q = msg.transform.rotation
    q.x, q.y, q.z, q.w = matrix_quaternion(R)
    return msg


def imu_specific_force(msg) -> np.ndarray:
    """World-frame specific force ``(3,)`` of a ``sensor_msgs/Imu`` (validated beforehand).

    ``linear_acceleration`` is in the IMU (body) frame; it is rotated by ``orientation`` when one is
    provided (``orientation_covariance[0] != -1``), else taken as already in world axes.
    """
    a = np.array([msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z])
    if imu_has_orientation(msg):
        q = msg.orientation
        a = quaternion_matrix(q.x, q.y, q.z, q.w) @ a
    return a


def imu_has_orientation(msg) -> bool:
    """REP 145 / sensor_msgs: ``orientation_covariance[0] == -1`` means no orientation estimate."""
    return float(msg.orientation_covariance[0]) != -1.0


# --- measurements ------------------------------------------------------------------------------------
def rae_values(msg) -> tuple[float, float, float]:
    """``geometry_msgs/Vector3Stamped`` -> ``(range [m], azimuth [rad], elevation [rad])``."""
    return float(msg.vector.x), float(msg.vector.y), float(msg.vector.z)


def position_fix(msg) -> tuple[np.ndarray, np.ndarray]:
    """``geometry_msgs/PoseWithCovarianceStamped`` -> position ``(3,)`` [m] and its covariance ``(3, 3)``."""
    p = msg.pose.pose.position
    return np.array([p.x, p.y, p.z], dtype=float), position_covariance(msg.pose.covariance)


def velocity_fix(msg) -> tuple[np.ndarray, np.ndarray]:
    """``geometry_msgs/TwistWithCovarianceStamped`` -> linear velocity ``(3,)`` [m/s] and its covariance
    ``(3, 3)`` (the linear block)."""
    v = msg.twist.twist.linear
    return np.array([v.x, v.y, v.z], dtype=float), position_covariance(msg.twist.covariance)


def position_covariance(pose_covariance) -> np.ndarray:
    """The ``(3, 3)`` position block of a row-major 6x6 ``PoseWithCovariance.covariance``."""
    return np.asarray(pose_covariance, dtype=float).reshape(6, 6)[:3, :3].copy()


# --- outputs -----------------------------------------------------------------------------------------
_ROTATION_BLOCK = np.eye(3) * UNKNOWN_ROTATION_VARIANCE


def _cov6(block: np.ndarray) -> np.ndarray:
    """Row-major 6x6 covariance ``(36,)`` float64 (a numpy array: rosidl's fast path, no per-element
    validation) with ``block`` as the linear part and the unknown-rotation diagonal."""
    out = np.zeros((6, 6))
    out[:3, :3] = block
    out[3:, 3:] = _ROTATION_BLOCK
    return out.reshape(36)


def odometry_msg(mean: np.ndarray, cov: np.ndarray, stamp_ns: int, world_frame: str, base_frame: str,
                 position_index=(0, 1, 2), velocity_index=(3, 4, 5)) -> Odometry:
    """``nav_msgs/Odometry`` of a state estimate (see the module docstring for the conventions)."""
    p, v = list(position_index), list(velocity_index)
    msg = Odometry()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id = world_frame
    msg.child_frame_id = base_frame
    pos = msg.pose.pose.position
    pos.x, pos.y, pos.z = (float(c) for c in mean[p])
    msg.pose.pose.orientation.w = 1.0
    msg.pose.covariance = _cov6(cov[np.ix_(p, p)])
    lin = msg.twist.twist.linear
    lin.x, lin.y, lin.z = (float(c) for c in mean[v])
    msg.twist.covariance = _cov6(cov[np.ix_(v, v)])
    return msg


def odometry_transform(odometry: Odometry, frame_id: str = "", child_frame_id: str = "") -> TransformStamped:
    """``geometry_msgs/TransformStamped`` of an odometry's pose, at its stamp: ``frame_id`` (default the
    odometry's ``header.frame_id``) to ``child_frame_id`` (default its ``child_frame_id``)."""
    msg = TransformStamped()
    msg.header.stamp = odometry.header.stamp
    msg.header.frame_id = frame_id or odometry.header.frame_id
    msg.child_frame_id = child_frame_id or odometry.child_frame_id
    pose = odometry.pose.pose
    t = msg.transform.translation
    t.x, t.y, t.z = pose.position.x, pose.position.y, pose.position.z
    msg.transform.rotation = pose.orientation
    return msg


def odometry_state(msg) -> np.ndarray:
    """``[x, y, z, vx, vy, vz]`` of a ``nav_msgs/Odometry``."""
    p, v = msg.pose.pose.position, msg.twist.twist.linear
    return np.array([p.x, p.y, p.z, v.x, v.y, v.z], dtype=float)


def decimate(particles: np.ndarray, weights: np.ndarray, k: int) -> np.ndarray:
    """Indices of at most ``k`` particles that represent the weighted set.

    Deterministic systematic selection (offset 1/2) on the cumulative weights, so heavy particles may
    repeat; all indices when ``N <= k``.
    """
    n = particles.shape[0]
    if n <= k:
        return np.arange(n)
    c = np.cumsum(weights)
    c[-1] = 1.0
    return np.minimum(np.searchsorted(c, (np.arange(k) + 0.5) / k), n - 1)


def pose_array_msg(positions: np.ndarray, stamp_ns: int, frame: str) -> PoseArray:
    """``geometry_msgs/PoseArray`` of positions ``(K, 3)`` with identity orientations."""
    msg = PoseArray()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id = frame
    poses = []
    for x, y, z in positions.tolist():
        pose = Pose()
        pose.position.x, pose.position.y, pose.position.z = x, y, z
        pose.orientation.w = 1.0
        poses.append(pose)
    msg.poses = poses
    return msg


def vector3_stamped(values, stamp_ns: int, frame: str) -> Vector3Stamped:
    """``geometry_msgs/Vector3Stamped`` with ``x, y, z = values``."""
    msg = Vector3Stamped()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id = frame
    msg.vector.x, msg.vector.y, msg.vector.z = (float(c) for c in values)
    return msg
