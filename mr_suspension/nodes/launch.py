"""Run the node set as separate processes with the recorder; read a run back from its bag.

A launch-free replacement of ``ros2 launch`` (not available as wheels): :func:`run_node_set`
starts recorder, controller, actuator and plant as ``python -m mr_suspension.nodes.<node>``
processes with one generated parameter file, waits for the plant to finish the road, stops the
others with SIGINT (the recorder closes its bag cleanly) and returns the bag path, a summary
read back from the bag, the offline simulator's summary and every node's statistics.
"""

import json
import os
from pathlib import Path
import random
import signal
import subprocess
import sys
import time

import numpy as np
from rosbags.rosbag2 import Reader
import yaml

from mr_suspension.core import road as rd
from mr_suspension.core.metrics import rms
from mr_suspension.core.simulator import simulate, summary
from mr_suspension.nodes import contract as c
from mr_suspension.nodes.common import corner_config

NODE_ORDER = ('recorder', 'controller', 'actuator', 'plant')
STOP_ORDER = ('plant', 'controller', 'actuator', 'recorder')
DEFAULT_ROAD = '{type: bump, height: 0.05}'


def offline_summary(config, road_spec, duration):
    """Summary of the offline simulator on the same road (the node set's reference)."""
    spec = yaml.safe_load(road_spec) if isinstance(road_spec, str) else dict(road_spec)
    return summary(simulate(config, rd.from_spec(spec, duration=duration, dt=config.dt)))


def read_bag(path):
    """Return ``{topic: (log_times_ns, [deserialized messages])}`` of a bag (empty -> error)."""
    from mr_suspension.nodes.cdr import typestore
    store = typestore()
    out = {}
    with Reader(path) as reader:
        if reader.message_count == 0:
            raise ValueError(f'{path}: the bag holds no messages')
        for conn, t, raw in reader.messages():
            times, msgs = out.setdefault(conn.topic, ([], []))
            times.append(t)
            msgs.append(store.deserialize_cdr(raw, conn.msgtype))
    return out


def bag_summary(path, namespace='', gravity=9.81):
    """Return the main figures of a node-set run, read back from its bag.

    Body acceleration from ``imu/body`` (gravity removed), working space from ``stroke``, dynamic
    tyre load from ``truth/tyre_force`` minus its first (static) sample. Sample 0 (the initial
    state) is dropped so sample ``k`` matches the simulator's row ``k - 1``.
    """
    data = read_bag(path)
    prefix = '/' + namespace.strip('/') + '/' if namespace.strip('/') else '/'

    def series(name):
        full = prefix + name
        if full not in data:
            raise ValueError(f'{path}: no messages on {full}')
        return data[full][1]

    acc = np.array([m.linear_acceleration.z for m in series(c.IMU_BODY)]) - gravity
    stroke = np.array([m.position[0] for m in series(c.STROKE)])
    tyre = np.array([m.data for m in series(c.TRUTH_TYRE_FORCE)])
    cmd = np.array([m.data for m in series(c.CURRENT_COMMAND)]) \
        if prefix + c.CURRENT_COMMAND in data else np.zeros(0)
    return {'samples': int(acc.size), 'body_acc_rms': rms(acc[1:]),
            'working_space_rms': rms(stroke[1:]), 'tyre_load_rms': rms(tyre[1:] - tyre[0]),
            'mean_current': float(np.mean(cmd)) if cmd.size else float('nan'),
            'counts': {t: len(v[1]) for t, v in sorted(data.items())}}


def agreement(nodes, offline):
    """Relative difference [%] of the node set's metrics from the offline simulator's."""
    return {k: 100.0 * (nodes[k] - offline[k]) / offline[k] for k in offline
            if k in nodes and offline[k] != 0.0}


def resolve_domain(domain_id=None):
    """Return the ``ROS_DOMAIN_ID`` for a node set: None keeps the user's, 'random' isolates.

    ``None``: the environment's ``ROS_DOMAIN_ID`` (unset: ROS's default, 0), so the node set is
    visible to the user's ``ros2`` tools; ``'random'``: a random domain in 1..100, for tests
    and benchmarks that must not see other graphs; an int: that domain.
    """
    if domain_id is None:
        return None
    if domain_id == 'random':
        return random.Random(os.getpid() ^ time.time_ns()).randint(1, 100)
    domain = int(domain_id)
    if not 0 <= domain <= 232:
        raise ValueError(f'domain id must be in 0..232, got {domain}')
    return domain


def _env(domain_id=None):
    """Environment of a node-set process: this one's, prepared for rclpy, on ``domain_id``.

    ``domain_id`` None keeps the environment's ``ROS_DOMAIN_ID`` (or its absence).
    """
    from mr_suspension.nodes.common import ensure_environment
    ensure_environment()  # also the Fast DDS profile, config/fastdds.xml
    env = dict(os.environ)
    if domain_id is not None:
        env['ROS_DOMAIN_ID'] = str(domain_id)
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    if env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'OFF':
        env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env.setdefault('PYTHONUNBUFFERED', '1')
    return env


def _tail(path, n=15):
    try:
        return '\n'.join(Path(path).read_text(encoding='utf-8').splitlines()[-n:])
    except OSError:
        return ''


def _stop(proc, timeout):
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5.0)
    return proc.returncode


def run_node_set(out_dir, duration=3.0, road=DEFAULT_ROAD, vehicle='city_car',
                 damper='rd1005_bingham', driver='wonder_box', controller='skyhook_onoff',
                 lockstep=True, rate=1000.0, storage='mcap', namespace='front_left',
                 domain_id=None, record=True, timeout=None, extra=None, coupling_delay=None):
    """Run plant, controller, actuator (and recorder) as separate processes; return the results.

    ``coupling_delay`` (lock-step; plant and actuator, default from ``config/nodes``: 1; 0 =
    the simulator's step order exactly). ``extra`` maps node name -> dict of further
    parameters. ``domain_id``: None (default) runs on the user's ``ROS_DOMAIN_ID``, 'random'
    on an isolated random domain (tests), or an int. Returns a dict with ``bag`` (path or
    None), ``summary`` (read back from the bag), ``offline`` (simulator), ``agreement`` [%],
    ``stats`` per node, ``returncodes`` and ``wall_s``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    bag = out / 'bag'
    if record and bag.exists():
        raise FileExistsError(f'{bag} exists; choose a new output directory')
    road = road if isinstance(road, str) else yaml.safe_dump(dict(road), default_flow_style=True)
    common = {'vehicle': vehicle, 'damper': damper, 'driver': driver, 'controller': controller,
              'rate': float(rate), 'lockstep': bool(lockstep)}
    nodes = [n for n in NODE_ORDER if record or n != 'recorder']
    params = {
        'plant': dict(common, road=road, duration=float(duration), exit_at_end=True,
                      expect_subscribers=2 if record else 1),
        'controller': dict(common, recorders=int(record)),
        'actuator': dict(common, recorders=int(record)),
        'recorder': {'output': str(bag), 'storage': storage, 'lockstep': bool(lockstep)},
    }
    if coupling_delay is not None:
        for name in ('plant', 'actuator'):
            params[name]['coupling_delay'] = int(coupling_delay)
    for name in nodes:
        params[name]['stats_file'] = str(out / f'stats_{name}.json')
        params[name].update((extra or {}).get(name, {}))
    param_file = out / 'params.yaml'
    with open(param_file, 'w', encoding='utf-8') as fh:
        yaml.safe_dump({f'/**/{n}': {'ros__parameters': params[n]} for n in nodes}, fh)
    env = _env(resolve_domain(domain_id))
    procs = {}
    t0 = time.monotonic()
    limit = timeout if timeout is not None else 60.0 + 20.0 * duration
    try:
        for name in nodes:
            log = open(out / f'{name}.log', 'w', encoding='utf-8')
            procs[name] = subprocess.Popen(
                [sys.executable, '-m', f'mr_suspension.nodes.{name}', '--ros-args', '-r',
                 f'__ns:=/{namespace}', '--params-file', str(param_file)],
                env=env, stdout=log, stderr=subprocess.STDOUT)
            log.close()
        end = time.monotonic() + limit
        while procs['plant'].poll() is None:
            for name, proc in procs.items():
                if name != 'plant' and proc.poll() is not None:
                    raise RuntimeError(f'{name} exited early with code {proc.returncode}:\n'
                                       + _tail(out / f'{name}.log'))
            if time.monotonic() > end:
                raise TimeoutError(f'node set did not finish within {limit:.0f} s; logs in '
                                   f'{out}')
            time.sleep(0.2)
        if procs['plant'].returncode != 0:
            raise RuntimeError(f'plant failed with code {procs["plant"].returncode}:\n'
                               + _tail(out / 'plant.log'))
    finally:
        # Stop the loop first, the recorder last so that it drains everything published.
        codes = {name: _stop(procs[name], 20.0) for name in STOP_ORDER if name in procs}
    wall = time.monotonic() - t0
    stats = {}
    for name in nodes:
        path = out / f'stats_{name}.json'
        if path.is_file():
            stats[name] = json.loads(path.read_text(encoding='utf-8'))
    result = {'bag': str(bag) if record else None, 'returncodes': codes, 'stats': stats,
              'wall_s': wall}
    config = corner_config(vehicle, damper, driver, controller, rate)
    result['offline'] = offline_summary(config, road, duration)
    if record:
        result['summary'] = bag_summary(bag, namespace, config.car.g)
        result['agreement'] = agreement(result['summary'], result['offline'])
    return result
