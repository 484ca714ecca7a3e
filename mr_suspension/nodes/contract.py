"""Topic contract of the node set, checked against ``msg_defs/topics.yaml``.

The YAML file is the human-readable contract; this module holds the same facts for the nodes
and the recorder, and :func:`check_against_yaml` (run by ``test/test_contract.py``) reports any
difference between the two. No ROS imports here.
"""

from dataclasses import dataclass
import os
from pathlib import Path

import yaml


@dataclass(frozen=True)
class Topic:
    """One contract topic."""

    name: str
    type: str  # noqa: A003 - the contract field name
    rate: float
    reliability: str
    depth: int
    units: str
    frame_id: str
    publisher: object  # a node name, or a tuple of node names
    subscribers: tuple
    optional_subscribers: tuple = ()  # subscribe only in some configurations
    recorded: bool = True  # recorded by default (a data topic)
    scope: str = 'corner'  # 'corner': in each corner's namespace; 'car': the car's namespace

    @property
    def publishers(self):
        """Publishing node names as a tuple."""
        return (self.publisher,) if isinstance(self.publisher, str) else tuple(self.publisher)


IMU_BODY = 'imu/body'
IMU_WHEEL = 'imu/wheel'
STROKE = 'stroke'
CURRENT_COMMAND = 'current_command'
COIL_CURRENT = 'coil_current'
DAMPER_FORCE = 'damper/force'
TRUTH_STATE = 'truth/state'
TRUTH_TYRE_FORCE = 'truth/tyre_force'
BODY_IMU = 'body/imu'  # the full car's body IMU at the centre of gravity (car namespace)
CLOCK = '/clock'
DIAGNOSTICS = '/diagnostics'
ABSOLUTE = (CLOCK, DIAGNOSTICS)  # the only names not relative to the corner's namespace
# The full car's corners: the namespaces of their topics, relative to the car's namespace.
CORNERS = ('front_left', 'front_right', 'rear_left', 'rear_right')
SCOPES = ('corner', 'car')

# Frames and joint names used in the messages.
FRAME_BODY_IMU = 'body_imu'
FRAME_BODY_IMU_CG = 'body_imu_cg'
FRAME_WHEEL_IMU = 'wheel_imu'
FRAME_SUSPENSION = 'suspension'
FRAME_WORLD = 'world'
JOINT_STROKE = 'suspension_stroke'
JOINTS_DAMPER = ('damper', 'damper_tangent')
JOINTS_TRUTH = ('body', 'wheel', 'road', 'suspension')

DEPTH = 1000
_R = 'reliable'
IMU = 'sensor_msgs/msg/Imu'
JOINT_STATE = 'sensor_msgs/msg/JointState'
FLOAT64 = 'std_msgs/msg/Float64'
CLOCK_TYPE = 'rosgraph_msgs/msg/Clock'
DIAGNOSTIC_ARRAY = 'diagnostic_msgs/msg/DiagnosticArray'
DIAGNOSTICS_DEPTH = 10

PLANTS = ('plant', 'full_car_plant')  # a quarter-car plant, or the full car for four corners
ALL_TOPICS = {t.name: t for t in (
    Topic(IMU_BODY, IMU, 1000, _R, DEPTH, 'm/s^2 (linear_acceleration)', FRAME_BODY_IMU,
          PLANTS, ('controller', 'recorder'), ('modal_controller',)),
    Topic(IMU_WHEEL, IMU, 1000, _R, DEPTH, 'm/s^2 (linear_acceleration)', FRAME_WHEEL_IMU,
          PLANTS, ('controller', 'recorder'), ('modal_controller',)),
    Topic(STROKE, JOINT_STATE, 1000, _R, DEPTH, 'm (position)', FRAME_SUSPENSION, PLANTS,
          ('controller', 'recorder'), ('modal_controller',)),
    Topic(CURRENT_COMMAND, FLOAT64, 1000, _R, DEPTH, 'A', '', ('controller', 'modal_controller'),
          ('actuator', 'recorder')),
    Topic(COIL_CURRENT, FLOAT64, 1000, _R, DEPTH, 'A', '', 'actuator', ('recorder',),
          ('controller', 'modal_controller')),
    Topic(DAMPER_FORCE, JOINT_STATE, 1000, _R, DEPTH, 'N (effort[0]), N s/m (effort[1]), m, m/s',
          FRAME_SUSPENSION, 'actuator', ('plant', 'recorder'), ('full_car_plant',)),
    Topic(TRUTH_STATE, JOINT_STATE, 1000, _R, DEPTH, 'm (position), m/s (velocity)',
          FRAME_WORLD, PLANTS, ('actuator', 'recorder')),
    Topic(TRUTH_TYRE_FORCE, FLOAT64, 1000, _R, DEPTH, 'N', '', PLANTS, ('recorder',)),
    Topic(BODY_IMU, IMU, 1000, _R, DEPTH, 'm/s^2 (linear_acceleration.z), rad/s '
          '(angular_velocity.x roll, .y pitch)', FRAME_BODY_IMU_CG, 'full_car_plant',
          ('modal_controller', 'recorder'), scope='car'),
    Topic(CLOCK, CLOCK_TYPE, 1000, _R, DEPTH, 's', '', PLANTS, ('recorder',)),
    Topic(DIAGNOSTICS, DIAGNOSTIC_ARRAY, 1, _R, DIAGNOSTICS_DEPTH, '', '',
          ('controller', 'actuator', 'modal_controller'), (), recorded=False),
)}
# The corner's data topics (what the recorder records by default), /clock included.
TOPICS = {n: t for n, t in ALL_TOPICS.items() if t.recorded and t.scope == 'corner'}
# The car's data topics (full car only): in the car's namespace, beside the corners'.
CAR_TOPICS = {n: t for n, t in ALL_TOPICS.items() if t.recorded and t.scope == 'car'}


def published_by(node, scope=None):
    """Names of the topics ``node`` publishes (``scope``: only those of that scope)."""
    return sorted(n for n, t in ALL_TOPICS.items()
                  if node in t.publishers and scope in (None, t.scope))


def subscribed_by(node, optional=False, scope=None):
    """Names of the topics ``node`` subscribes to (``optional``: also those it may)."""
    return sorted(n for n, t in ALL_TOPICS.items()
                  if (node in t.subscribers or (optional and node in t.optional_subscribers))
                  and scope in (None, t.scope))


def yaml_path():
    """Path of ``msg_defs/topics.yaml`` (source tree, then the installed share directory)."""
    env = os.environ.get('MR_SUSPENSION_MSG_DEFS')
    if env:
        return Path(env) / 'topics.yaml'
    from mr_suspension.core.paramsets import share_dir  # source, ament index, <prefix>/share
    return share_dir('msg_defs') / 'topics.yaml'


def load_yaml(path=None):
    """Return the ``topics`` mapping of the YAML contract."""
    with open(path or yaml_path(), encoding='utf-8') as fh:
        data = yaml.safe_load(fh)
    return data['topics']


def check_against_yaml(path=None):
    """Return a list of differences between this module and the YAML contract (empty: agree)."""
    doc = load_yaml(path)
    errors = []
    for name in sorted(set(doc) ^ set(ALL_TOPICS)):
        errors.append(f'{name}: only in {"YAML" if name in doc else "contract.py"}')
    for name in sorted(set(doc) & set(ALL_TOPICS)):
        y, t = doc[name], ALL_TOPICS[name]
        pub = y.get('publisher')
        got = {'type': y.get('type'), 'rate': float(y.get('rate')),
               'reliability': y.get('qos', {}).get('reliability'),
               'depth': y.get('qos', {}).get('depth'), 'units': y.get('units'),
               'frame_id': y.get('frame_id'),
               'publisher': tuple(pub) if isinstance(pub, list) else pub,
               'subscribers': tuple(y.get('subscribers', ())),
               'optional_subscribers': tuple(y.get('optional_subscribers', ())),
               'recorded': y.get('recorded', True), 'scope': y.get('scope', 'corner')}
        for key, value in got.items():
            if value != getattr(t, key) and not (key == 'rate' and value == float(t.rate)):
                errors.append(f'{name}.{key}: YAML {value!r} != contract.py {getattr(t, key)!r}')
        if name.startswith('/') and name not in ABSOLUTE:
            errors.append(f'{name}: names must be relative (except {", ".join(ABSOLUTE)})')
        if t.scope not in SCOPES:
            errors.append(f'{name}.scope: {t.scope!r} is not one of {SCOPES}')
    return errors
