"""The fast CDR readers agree with rclpy's deserializer."""

import math
import random

from rclpy.serialization import serialize_message
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Float64

from mr_suspension.nodes import cdr


def test_readers_match_rclpy():
    rng = random.Random(3)
    for trial in range(300):
        frame = 'f' * rng.randint(0, 13)
        imu = Imu()
        imu.header.frame_id = frame
        imu.header.stamp.sec = rng.randint(0, 2 ** 31 - 1)
        imu.header.stamp.nanosec = rng.randint(0, 999_999_999)
        imu.linear_acceleration.z = rng.uniform(-50, 50)
        imu.linear_acceleration.x = rng.uniform(-50, 50)
        imu.orientation.w = rng.random()
        stamp = imu.header.stamp.sec * 1_000_000_000 + imu.header.stamp.nanosec
        assert cdr.imu_acc_z(serialize_message(imu)) == (stamp, imu.linear_acceleration.z)
        js = JointState()
        js.header.frame_id = frame
        js.header.stamp = imu.header.stamp
        n = rng.randint(0, 4)
        js.name = ['j' * rng.randint(0, 9) for _ in range(n)]
        js.position = [rng.uniform(-1, 1) for _ in range(rng.choice([0, n]))]
        js.velocity = [rng.uniform(-1, 1) for _ in range(rng.choice([0, n]))]
        js.effort = [rng.uniform(-1e4, 1e4) for _ in range(rng.choice([0, n]))]
        assert cdr.joint_state(serialize_message(js)) == (
            stamp, list(js.position), list(js.velocity), list(js.effort)), trial
        value = rng.uniform(-5, 5)
        assert cdr.float64(serialize_message(Float64(data=value))) == value
    assert math.isnan(cdr.float64(serialize_message(Float64(data=math.nan))))


def test_template_bytes_are_exact_cdr():
    """Patched templates equal rosbags' serialization and read back in rclpy and rosbags."""
    from rclpy.serialization import deserialize_message
    from rosgraph_msgs.msg import Clock
    store = cdr.typestore()
    rng = random.Random(5)
    imu = Imu()
    imu.header.frame_id = 'body_imu'
    imu.orientation_covariance[0] = -1.0
    js = JointState()
    js.header.frame_id = 'world'
    js.name = ['body', 'wheel', 'road', 'suspension']
    js.position = [0.0] * 4
    js.velocity = [0.0] * 4
    stroke = JointState()
    stroke.name = ['suspension_stroke']
    stroke.position = [0.0]
    t_imu = cdr.Template(imu, ('linear_acceleration.z',))
    slots = [f'position[{i}]' for i in range(4)] + [f'velocity[{i}]' for i in range(4)]
    t_js = cdr.Template(js, slots)
    t_stroke = cdr.Template(stroke, ('position[0]',))
    t_f = cdr.Template(Float64(), ('data',), stamped=False)
    t_clock = cdr.Template(Clock(), (), stamped=True)
    for _ in range(100):
        ns = rng.randint(0, (2 ** 31 - 1) * 1_000_000_000)
        sec, nsec = divmod(ns, 1_000_000_000)
        az = rng.uniform(-100, 100)
        imu.header.stamp.sec, imu.header.stamp.nanosec = sec, nsec
        imu.linear_acceleration.z = az
        raw = t_imu.pack(ns, az)
        assert raw == cdr.serialize(imu)
        assert deserialize_message(raw, Imu) == imu
        assert cdr.imu_acc_z(raw) == (ns, az)
        values = [rng.uniform(-1, 1) for _ in range(8)]
        js.header.stamp.sec, js.header.stamp.nanosec = sec, nsec
        js.position, js.velocity = values[:4], values[4:]
        raw = t_js.pack(ns, *values)
        assert raw == cdr.serialize(js)
        assert deserialize_message(raw, JointState) == js
        assert cdr.joint_state(raw) == (ns, values[:4], values[4:], [])
        read = store.deserialize_cdr(raw, 'sensor_msgs/msg/JointState')
        assert list(read.position) == values[:4] and read.name == js.name
        raw = t_stroke.pack(ns, az)
        assert store.deserialize_cdr(raw, 'sensor_msgs/msg/JointState').position[0] == az
        assert cdr.float64(t_f.pack(0, az)) == az
        assert deserialize_message(t_f.pack(0, az), Float64).data == az
        clock = deserialize_message(t_clock.pack(ns), Clock)
        assert (clock.clock.sec, clock.clock.nanosec) == (sec, nsec)


def test_template_rejects_unknown_or_missing_slots():
    import pytest
    with pytest.raises(AttributeError):
        cdr.Template(Imu(), ('linear_acceleration.w',))
    with pytest.raises(IndexError):
        cdr.Template(JointState(), ('position[0]',))


def test_stamp_of_stamped_messages_and_clock():
    from rosgraph_msgs.msg import Clock
    ns = 12 * 1_000_000_000 + 345_678_901
    for tpl in (cdr.Template(Imu(), ('linear_acceleration.z',)), cdr.Template(Clock(), ()),
                cdr.Template(JointState(), ())):
        raw = tpl.pack(ns, *([1.0] * len(tpl.offsets)))
        assert cdr.stamp(raw) == ns
    assert cdr.stamp(b'\x00\x00' + bytes(10)) is None  # big-endian CDR: not read here
