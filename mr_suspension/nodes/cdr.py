"""Fast readers for the few fields the nodes need from serialized (CDR) contract messages.

Building a Python message object costs about 45 us for an ``Imu`` or a ``JointState``; at 1 kHz
and three to four messages per node and step that is a large share of the loop. The nodes
therefore subscribe with ``raw=True`` and read the fields they need straight from the
little-endian plain CDR (XCDR1) that ROS 2 middlewares send, with ``struct`` (about 1 us).
Anything else (big-endian or XCDR2 encapsulation) falls back to ``rclpy``'s deserializer, so the
readers are always correct; ``test/test_nodes_cdr.py`` checks them against it.
"""

import math
import struct

from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Float64

_I3 = struct.Struct('<iII')
_U32 = struct.Struct('<I')
_D = struct.Struct('<d')
_IMU_SKIP = 8 * (4 + 9 + 3 + 9)  # orientation, its covariance, angular velocity, covariance


def _plain_le(raw):
    return raw[0:2] == b'\x00\x01'


def _header(raw):
    """Return (stamp in ns, payload offset after the header) of a stamped message."""
    sec, nsec, n = _I3.unpack_from(raw, 4)
    return sec * 1_000_000_000 + nsec, 12 + n


def _doubles(raw, off):
    """Read a ``sequence<double>`` at payload offset ``off``; return (list, new offset)."""
    off = (off + 3) & ~3
    (n,) = _U32.unpack_from(raw, 4 + off)
    off += 4
    if n == 0:
        return [], off
    off = (off + 7) & ~7
    values = list(struct.unpack_from(f'<{n}d', raw, 4 + off))
    return values, off + 8 * n


def imu_acc_z(raw):
    """Return (stamp ns, linear_acceleration.z) of a serialized ``sensor_msgs/Imu``."""
    if not _plain_le(raw):
        msg = deserialize_message(raw, Imu)
        s = msg.header.stamp
        return s.sec * 1_000_000_000 + s.nanosec, msg.linear_acceleration.z
    stamp, off = _header(raw)
    off = (off + 7) & ~7
    (az,) = _D.unpack_from(raw, 4 + off + _IMU_SKIP + 16)
    return stamp, az


def joint_state(raw):
    """Return (stamp ns, position, velocity, effort) of a serialized ``JointState``."""
    if not _plain_le(raw):
        msg = deserialize_message(raw, JointState)
        s = msg.header.stamp
        return (s.sec * 1_000_000_000 + s.nanosec, list(msg.position), list(msg.velocity),
                list(msg.effort))
    stamp, off = _header(raw)
    off = (off + 3) & ~3
    (n,) = _U32.unpack_from(raw, 4 + off)
    off += 4
    for _ in range(n):
        off = (off + 3) & ~3
        (length,) = _U32.unpack_from(raw, 4 + off)
        off += 4 + length
    position, off = _doubles(raw, off)
    velocity, off = _doubles(raw, off)
    effort, off = _doubles(raw, off)
    return stamp, position, velocity, effort


def float64(raw):
    """Return the value of a serialized ``std_msgs/Float64``."""
    if not _plain_le(raw):
        return deserialize_message(raw, Float64).data
    if len(raw) < 12:
        return math.nan
    return _D.unpack_from(raw, 4)[0]
