"""Truth records for the tests: ``mr_suspension.truth`` cases from a seed range of their own.

The diagnosis benchmark draws its cases from seeds below one million (its seed set times a
prime near 1e5, plus the case number); a test drawn from those seeds would judge the code
on the very cases it was tuned on. Tests draw their truths here instead, from ``BASE + n``,
and name the physical situation by the arguments (shape, effects, strengths, sensor faults)
and by asserts on the drawn truth.
"""

from pathlib import Path
import warnings

import numpy as np

from mr_suspension.identification import data as dataio
from mr_suspension.truth import cases, rig
from mr_suspension.truth import full_car as fc

BASE = 7_000_000
SPAN = 1_000_000


def case(n, effects=(), **kwargs):
    """Draw the truth case of seed ``BASE + n`` (``0 <= n < SPAN``): ``cases.make_case``."""
    if not 0 <= n < SPAN:
        raise ValueError(f'truthcases.case: n must be in [0, {SPAN}), got {n}')
    return cases.make_case(BASE + n, effects, **kwargs)


def record(columns, name='case'):
    """Build a ``data.Record`` from a case's columns (input warnings silenced)."""
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        return dataio.build_record(name, columns)


def sine(freq=2.0, amp=0.01, duration=3.0, rate=1000.0):
    """Return ``(t, x)``: a displacement sine of ``freq`` [Hz] and ``amp`` [m]."""
    t = np.arange(int(round(duration * rate))) / rate
    return t, amp * np.sin(2 * np.pi * freq * t)


def linear_truth(**kw):
    """Return a purely viscous rig truth: no yield, no current dependence, no driver lag."""
    base = {'f0': 0.0, 'c0': 1500.0, 'c1': 0.0, 'fy0': 0.0, 'fy1': 0.0, 'driver_tau': 0.0}
    base.update(kw)
    return rig.RigTruth(**base)


def write_full_car_bag(case, path):
    """Write ``case`` as a rosbag2 (version 9, sqlite3) of the contract topics; return the path.

    The four corners under their namespaces and the body IMU: :func:`write_contract_bag`.
    """
    return write_contract_bag(path, case.body['time'],
                              {name: case.columns[name] for name in fc.CORNERS}, case.body)


def write_contract_bag(path, time, corners, body=None):
    """Write corner columns as a rosbag2 (version 9, sqlite3) of the contract topics.

    ``corners``: namespace -> columns (``body_acc``, ``wheel_acc``, ``stroke``,
    ``current_command``, optional ``coil_current``). Per namespace (``/front_left/...``):
    ``imu/body`` and ``imu/wheel`` (``sensor_msgs/Imu``, ``linear_acceleration.z`` = the
    column), ``stroke`` (``sensor_msgs/JointState``, joint ``suspension_stroke``),
    ``current_command`` and ``coil_current`` (``std_msgs/Float64``); with ``body``
    (``pitch_rate``, ``roll_rate``, ``acc_z``) also ``/body/imu`` (``sensor_msgs/Imu``,
    ``angular_velocity.y`` the pitch rate, ``.x`` the roll rate, ``linear_acceleration.z`` the
    vertical specific force). Header stamps ``1 s + t``; unknown Imu fields have covariance[0]
    = -1 (the contract's convention). Returns the path.
    """
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import get_typestore, Stores

    path = Path(path)
    ts = get_typestore(Stores.LATEST)
    imu, js = ts.types['sensor_msgs/msg/Imu'], ts.types['sensor_msgs/msg/JointState']
    f64, hdr = ts.types['std_msgs/msg/Float64'], ts.types['std_msgs/msg/Header']
    stamp_t, vec = ts.types['builtin_interfaces/msg/Time'], ts.types['geometry_msgs/msg/Vector3']
    quat = ts.types['geometry_msgs/msg/Quaternion']
    unknown = np.zeros(9)
    unknown[0] = -1.0
    known = np.zeros(9)
    ident = quat(x=0.0, y=0.0, z=0.0, w=1.0)
    zero = vec(x=0.0, y=0.0, z=0.0)
    empty = np.array([], dtype=float)
    time = np.asarray(time, dtype=float)
    stamps = np.rint(1e9 + time * 1e9).astype(np.int64).tolist()
    secs = [s // 10 ** 9 for s in stamps]
    nsecs = [s % 10 ** 9 for s in stamps]

    def imu_msg(h, a, gyro=None):
        return imu(header=h, orientation=ident, orientation_covariance=unknown,
                   angular_velocity=zero if gyro is None else gyro,
                   angular_velocity_covariance=unknown if gyro is None else known,
                   linear_acceleration=vec(x=0.0, y=0.0, z=a),
                   linear_acceleration_covariance=known)

    with Writer(path, version=9) as w:
        streams = []
        for name, cols in corners.items():
            ns = name.strip('/')
            topics = [('imu/body', 'body_acc', imu), ('imu/wheel', 'wheel_acc', imu),
                      ('stroke', 'stroke', js), ('current_command', 'current_command', f64)]
            if 'coil_current' in cols:
                topics.append(('coil_current', 'coil_current', f64))
            for rel, col, ty in topics:
                conn = w.add_connection(f'/{ns}/{rel}', ty.__msgtype__, typestore=ts)
                streams.append((conn, rel, ty, np.asarray(cols[col], dtype=float).tolist()))
        if body is not None:
            body_conn = w.add_connection('/body/imu', imu.__msgtype__, typestore=ts)
            pitch = np.asarray(body['pitch_rate'], dtype=float).tolist()
            roll = np.asarray(body['roll_rate'], dtype=float).tolist()
            acc_z = np.asarray(body['acc_z'], dtype=float).tolist()
        frames = {'imu/body': 'body_imu', 'imu/wheel': 'wheel_imu', 'stroke': 'suspension'}
        headers = {f: [None] * len(stamps) for f in (*frames.values(), 'body_imu_cg')}
        for f, hs in headers.items():
            for k in range(len(stamps)):
                hs[k] = hdr(stamp=stamp_t(sec=secs[k], nanosec=nsecs[k]), frame_id=f)
        for k, ns_t in enumerate(stamps):
            for conn, rel, ty, vals in streams:
                if rel.startswith('imu/'):
                    msg = imu_msg(headers[frames[rel]][k], vals[k])
                elif rel == 'stroke':
                    msg = js(header=headers['suspension'][k], name=['suspension_stroke'],
                             position=np.array([vals[k]]), velocity=empty, effort=empty)
                else:
                    msg = f64(data=vals[k])
                w.write(conn, ns_t, ts.serialize_cdr(msg, ty.__msgtype__))
            if body is not None:
                msg = imu_msg(headers['body_imu_cg'][k], acc_z[k],
                              vec(x=roll[k], y=pitch[k], z=0.0))
                w.write(body_conn, ns_t, ts.serialize_cdr(msg, imu.__msgtype__))
    return path
