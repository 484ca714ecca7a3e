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
