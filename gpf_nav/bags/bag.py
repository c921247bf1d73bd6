"""rosbag2 bags (MCAP or sqlite3) of our ROS messages, through the pure-Python ``rosbags`` library.

Messages are the rclpy message objects the nodes publish, serialised by rclpy itself
(``rclpy.serialization``: CDR with its encapsulation header, as a ROS 2 recorder stores them). The bag's
type names, message definitions and type hashes (``RIHS01``) come from ``rosbags``' ROS 2 Jazzy type
store, so ``ros2 bag play`` and other readers (e.g. ``mcap-ros2-support``) decode them. Bags are written
in rosbag2 format version 9 (Jazzy) with ``metadata.yaml`` and each topic's offered QoS profile.

Every failure to open or read a bag is raised as :class:`BagError` with a one-line message.
"""
from __future__ import annotations

import struct
from functools import lru_cache
from pathlib import Path
from typing import Iterator

from rclpy.serialization import deserialize_message, serialize_message

STORAGES = ("mcap", "sqlite3")
INFINITE = (9223372036, 854775807)  # rmw's "infinite" duration (sec, nsec), as ros2 bag record writes it


class BagError(Exception):
    """A bag that cannot be written, opened or read; the message is one line."""


def type_name(msg_type) -> str:
    """ROS 2 type name of an rclpy message class, e.g. ``geometry_msgs/msg/Vector3Stamped``."""
    return f"{msg_type.__module__.split('.')[0]}/msg/{msg_type.__name__}"


def absolute(topic: str) -> str:
    """A node's topic name resolved in the root namespace (``imu`` -> ``/imu``)."""
    return topic if topic.startswith("/") else "/" + topic


@lru_cache(maxsize=1)
def _typestore():
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


def qos_profile(reliable: bool, depth: int, transient_local: bool = False):
    """A rosbag2 offered QoS profile: keep-last ``depth``, reliable or best effort, volatile or (latched)
    transient local."""
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability,
                                    QosTime)
    infinite = QosTime(*INFINITE)
    return Qos(QosHistory.KEEP_LAST, depth,
               QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
               QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE, infinite, infinite,
               QosLiveliness.AUTOMATIC, infinite, False)


class BagWriter:
    """Writes rclpy messages into a new bag directory; use as a context manager.

    Args:
        path: the bag directory to create (must not exist).
        storage: ``mcap`` or ``sqlite3``.
        topics: absolute topic name -> ``(message class, offered QoS profile)``.
    Attributes:
        counts: messages written per topic.
    """

    def __init__(self, path: str | Path, storage: str, topics: dict):
        from rosbags.rosbag2 import StoragePlugin, Writer
        if storage not in STORAGES:
            raise BagError(f"storage {storage!r} is not one of {', '.join(STORAGES)}")
        path = Path(path)
        if path.exists():
            raise BagError(f"{path} exists already; rosbag2 bags are never overwritten")
        self._writer = Writer(path, version=9, storage_plugin=StoragePlugin[storage.upper()])
        self._writer.open()
        self._connections = {}
        for topic, (msg_type, qos) in topics.items():
            self._connections[topic] = self._writer.add_connection(
                topic, type_name(msg_type), typestore=_typestore(), offered_qos_profiles=[qos])
        self.counts = {topic: 0 for topic in topics}
        self.path = path

    def write(self, topic: str, msg, t_ns: int) -> None:
        """Append ``msg`` on ``topic`` with recording time ``t_ns`` [ns of ROS time]."""
        self._writer.write(self._connections[topic], int(t_ns), serialize_message(msg))
        self.counts[topic] += 1

    def close(self) -> None:
        """Finish the storage file and write ``metadata.yaml``."""
        self._writer.close()

    def abort(self) -> None:
        """Stop without a valid bag (after an error)."""
        self._writer.abort()

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


class BagReader:
    """Reads a rosbag2 bag (directory with ``metadata.yaml``, MCAP or sqlite3); use as a context manager.

    Attributes:
        topics: absolute topic name -> type name, of every topic in the bag.
        counts: absolute topic name -> message count (from the bag's metadata).
        start_ns, end_ns: first and last recording time [ns].
    """

    def __init__(self, path: str | Path):
        from rosbags.rosbag2 import Reader
        path = Path(path)
        if not path.exists():
            raise BagError(f"{path}: no such bag")
        try:
            self._reader = Reader(path)
            self._reader.open()
        except Exception as err:  # noqa: BLE001 - rosbags raises several kinds; the user needs one line
            raise BagError(f"cannot open bag {path}: {_one_line(err)}") from None
        self.path = path
        self.topics = {c.topic: c.msgtype for c in self._reader.connections}
        self.counts: dict[str, int] = {}
        for c in self._reader.connections:
            self.counts[c.topic] = self.counts.get(c.topic, 0) + c.msgcount
        self.start_ns = self._reader.start_time if self._reader.message_count else 0
        self.end_ns = self._reader.end_time - 1 if self._reader.message_count else 0  # rosbags: "after the latest"

    def messages(self, topics) -> Iterator[tuple[str, int, bytes]]:
        """``(topic, recording time [ns], serialised message)`` of ``topics`` in recording-time order."""
        wanted = [c for c in self._reader.connections if c.topic in set(topics)]
        if not wanted:
            return
        try:
            for connection, t_ns, raw in self._reader.messages(connections=wanted):
                yield connection.topic, t_ns, raw
        except Exception as err:  # noqa: BLE001
            raise BagError(f"cannot read bag {self.path}: {_one_line(err)}") from None

    def close(self) -> None:
        self._reader.close()

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()


def deserialize(raw: bytes, msg_type):
    """The rclpy message of class ``msg_type`` in ``raw`` (raises on malformed data)."""
    return deserialize_message(bytes(raw), msg_type)


def header_stamp_ns(raw) -> int:
    """The ``header.stamp`` [ns] of a serialised message that starts with a ``std_msgs/Header`` (every
    stamped type), read from the CDR bytes without decoding the rest; ValueError when too short."""
    if len(raw) < 12:
        raise ValueError("shorter than a CDR header stamp")
    sec, nanosec = struct.unpack_from("<iI" if raw[1] & 1 else ">iI", raw, 4)  # byte 1: little endian
    return sec * 1_000_000_000 + nanosec


def _one_line(err: Exception) -> str:
    text = " ".join(str(err).split()) or type(err).__name__
    return text if len(text) <= 300 else text[:297] + "..."
