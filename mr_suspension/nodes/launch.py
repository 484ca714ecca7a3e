"""Run the node set as separate processes with the recorder; read a run back from its bag.

A launch-free replacement of ``ros2 launch`` (not available as wheels; the packaged
``launch/corner.launch.py`` and ``launch/full_car.launch.py`` start the same nodes with a ROS 2
install): :func:`run_node_set` starts recorder, controller, actuator and plant of one corner,
:func:`run_full_car` the full-car plant, four corner controllers (or the modal controller),
four actuators and one recorder, as ``python -m mr_suspension.nodes.<node>`` processes with one
generated parameter file; both wait for the plant to finish the road, stop the others with
SIGINT (the recorder closes its bag cleanly) and return the bag path, a summary read back from
the bag, the offline simulator's summary and every node's statistics.
"""

from dataclasses import fields
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

from mr_suspension.core import car_road, road as rd
from mr_suspension.core.metrics import rms
from mr_suspension.nodes import contract as c
from mr_suspension.nodes.common import (corner_config, corner_sets, corner_vehicle,
                                        full_car_config)
from mr_suspension.sim.simulator import simulate, summary

NODE_ORDER = ('recorder', 'controller', 'actuator', 'plant')
STOP_ORDER = ('plant', 'controller', 'actuator', 'recorder')
DEFAULT_ROAD = '{type: bump, height: 0.05}'
FULL_CAR_ROAD = '{type: bump, height: 0.05, side: left}'
# Full car: (executable, namespace) in start order; '' is the car's namespace.
FULL_CAR_STOP_ORDER = ('full_car_plant', 'modal_controller', 'controller', 'actuator',
                       'recorder')  # (the composed process is labelled full_car_plant)


def corner_nodes(namespace='front_left', record=True):
    """Nodes of a one-corner set as ``(executable, name, namespace)`` in start order."""
    return [(n, n, namespace) for n in NODE_ORDER if record or n != 'recorder']


def full_car_nodes(modal=False, record=True):
    """Nodes of the full-car set as ``(executable, name, namespace)`` in start order.

    The car's nodes (recorder, modal controller, full-car plant) in the car's namespace
    (``''``), each corner's controller (unless ``modal``) and actuator in the corner's.
    """
    nodes = [('recorder', 'recorder', '')] if record else []
    if modal:
        nodes.append(('modal_controller', 'modal_controller', ''))
    else:
        nodes += [('controller', 'controller', corner) for corner in c.CORNERS]
    nodes += [('actuator', 'actuator', corner) for corner in c.CORNERS]
    return nodes + [('full_car_plant', 'full_car_plant', '')]


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
    codes, stats, wall = _launch(out, corner_nodes(namespace, record), param_file, 'plant',
                                 STOP_ORDER, domain_id,
                                 timeout if timeout is not None else 60.0 + 20.0 * duration,
                                 by_name=True)
    result = {'bag': str(bag) if record else None, 'returncodes': codes, 'stats': stats,
              'wall_s': wall}
    config = corner_config(vehicle, damper, driver, controller, rate)
    result['offline'] = offline_summary(config, road, duration)
    if record:
        result['summary'] = bag_summary(bag, namespace, config.car.g)
        result['agreement'] = agreement(result['summary'], result['offline'])
    return result


def _label(name, namespace):
    return f'{namespace}/{name}' if namespace else name


def _process_nodes(nodes, composed, modal):
    """Return the processes to start: one per node, or the composed loop and the recorder."""
    if not composed:
        return nodes
    argv = ['--modal'] if modal else []
    return [n for n in nodes if n[0] == 'recorder'] + [
        ('full_car_composed', 'full_car_plant', None, argv)]


def _launch(out, nodes, param_file, plant, stop_order, domain_id, limit, by_name=False,
            stats_labels=()):
    """Start ``nodes`` ``(executable, name, namespace)``; wait for ``plant``; stop in order.

    Returns ``(return codes, statistics, wall time)`` keyed by ``[namespace/]name`` (by
    ``name`` alone with ``by_name``: one namespace). A namespace None starts the process
    without a namespace remap (it places its nodes itself); a fourth element adds arguments.
    ``stats_labels``: labels of further statistics files (nodes inside composed processes).
    """
    env = _env(resolve_domain(domain_id))
    procs = {}
    t0 = time.monotonic()
    try:
        for exe, name, ns, *more in nodes:
            label = name if by_name else _label(name, ns)
            log = open(out / f'{label.replace("/", "_")}.log', 'w', encoding='utf-8')
            remap = [] if ns is None else ['-r', f'__ns:=/{ns}']
            argv = list(more[0]) if more else []
            procs[label] = subprocess.Popen(
                [sys.executable, '-m', f'mr_suspension.nodes.{exe}'] + argv
                + ['--ros-args'] + remap + ['--params-file', str(param_file)],
                env=env, stdout=log, stderr=subprocess.STDOUT)
            log.close()
        end = time.monotonic() + limit
        while procs[plant].poll() is None:
            for label, proc in procs.items():
                if label != plant and proc.poll() is not None:
                    raise RuntimeError(f'{label} exited early with code {proc.returncode}:\n'
                                       + _tail(out / f'{label.replace("/", "_")}.log'))
            if time.monotonic() > end:
                raise TimeoutError(f'node set did not finish within {limit:.0f} s; logs in '
                                   f'{out}')
            time.sleep(0.2)
        if procs[plant].returncode != 0:
            raise RuntimeError(f'{plant} failed with code {procs[plant].returncode}:\n'
                               + _tail(out / f'{plant}.log'))
    finally:
        # Stop the loop first, the recorder last so that it drains everything published.
        order = sorted(procs, key=lambda lb: stop_order.index(lb.rpartition('/')[2]))
        codes = {label: _stop(procs[label], 20.0) for label in order}
    wall = time.monotonic() - t0
    stats = {}
    for label in list(procs) + list(stats_labels):
        path = out / f'stats_{label.replace("/", "_")}.json'
        if path.is_file():
            stats[label] = json.loads(path.read_text(encoding='utf-8'))
    return codes, stats, wall


def full_car_road(road_spec, duration, config):
    """Return the four-wheel road of a spec (YAML text or mapping) for a full-car config."""
    spec = yaml.safe_load(road_spec) if isinstance(road_spec, str) else dict(road_spec)
    return car_road.from_spec(spec, duration=duration, dt=config.dt,
                              wheelbase=config.car.wheelbase, track=config.car.track_f)


def full_car_offline(config, road_spec, duration):
    """Figures of the offline full-car simulator (the full-car node set's reference).

    Per corner (suffix ``_fl``, ``_fr``, ``_rl``, ``_rr``): RMS body-point acceleration,
    working space and dynamic tyre load; body: RMS heave acceleration at the CG, pitch and
    roll rate.
    """
    from mr_suspension.sim.full_car_sim import simulate as simulate_car
    res = simulate_car(config, full_car_road(road_spec, duration, config))
    out = {'heave_acc_rms': rms(res.channel('a_z')),
           'pitch_rate_rms': rms(res.channel('w_pitch')),
           'roll_rate_rms': rms(res.channel('w_roll'))}
    for i, tag in enumerate(CORNER_TAGS):
        static = config.car.corner(i).static_tyre_load
        out[f'body_acc_rms_{tag}'] = rms(res.channel('a_s', i))
        out[f'working_space_rms_{tag}'] = rms(res.channel('stroke', i))
        out[f'tyre_load_rms_{tag}'] = rms(res.channel('f_t', i) - static)
    return out


CORNER_TAGS = ('fl', 'fr', 'rl', 'rr')


def full_car_bag_summary(path, gravity=9.81, namespace=''):
    """Return the figures of :func:`full_car_offline`, read back from a full-car run's bag.

    Sample 0 (the initial state) is dropped so that sample ``k`` matches the simulator's row
    ``k - 1``; ``samples`` counts the body IMU's, ``counts`` the messages per topic.
    """
    data = read_bag(path)
    prefix = '/' + namespace.strip('/') + '/' if namespace.strip('/') else '/'

    def series(name):
        full = prefix + name
        if full not in data:
            raise ValueError(f'{path}: no messages on {full}')
        return data[full][1]

    body = series(c.BODY_IMU)
    a_z = np.array([m.linear_acceleration.z for m in body]) - gravity
    out = {'samples': int(a_z.size), 'heave_acc_rms': rms(a_z[1:]),
           'pitch_rate_rms': rms(np.array([m.angular_velocity.y for m in body])[1:]),
           'roll_rate_rms': rms(np.array([m.angular_velocity.x for m in body])[1:])}
    for corner, tag in zip(c.CORNERS, CORNER_TAGS):
        acc = np.array([m.linear_acceleration.z for m in series(f'{corner}/{c.IMU_BODY}')])
        stroke = np.array([m.position[0] for m in series(f'{corner}/{c.STROKE}')])
        tyre = np.array([m.data for m in series(f'{corner}/{c.TRUTH_TYRE_FORCE}')])
        out[f'body_acc_rms_{tag}'] = rms(acc[1:] - gravity)
        out[f'working_space_rms_{tag}'] = rms(stroke[1:])
        out[f'tyre_load_rms_{tag}'] = rms(tyre[1:] - tyre[0])
    out['counts'] = {t: len(v[1]) for t, v in sorted(data.items())}
    return out


def run_full_car(out_dir, duration=3.0, road=FULL_CAR_ROAD, vehicle='lisa_full_car',
                 damper='rd1005_bingham', driver='wonder_box', controller=None, modal=False,
                 lockstep=True, rate=1000.0, storage='mcap', domain_id=None, record=True,
                 timeout=None, extra=None, coupling_delay=None, composed=False):
    """Run the full-car node set as separate processes into one bag; return the results.

    Full-car plant, four corner controllers (or with ``modal`` the modal controller), four
    actuators (each corner's in its namespace, vehicle ``<vehicle>:<corner>``) and the
    recorder of every corner's topics and the body IMU. ``controller``: the corner law
    (default ``skyhook_onoff``, with ``modal`` ``skyhook``: the corners' estimation and inverse
    model). ``extra`` maps an executable (or ``<corner>/<executable>``) to further parameters.
    ``coupling_delay`` (lock-step) defaults to 0 here: the simulator's step order, so the bag
    equals :func:`full_car_offline` to round-off (1 runs plant and actuators concurrently,
    faster, with the one-sample coupling error). Other arguments and the result as
    :func:`run_node_set`, the figures those of :func:`full_car_offline` (``agreement`` [%]).
    ``composed``: plant, controllers and actuators in one process
    (:mod:`~mr_suspension.nodes.full_car_composed`), the recorder in its own.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    bag = out / 'bag'
    if record and bag.exists():
        raise FileExistsError(f'{bag} exists; choose a new output directory')
    if controller is None:
        controller = 'skyhook' if modal else 'skyhook_onoff'
    if coupling_delay is None and lockstep:
        coupling_delay = 0
    road = road if isinstance(road, str) else yaml.safe_dump(dict(road), default_flow_style=True)
    model = {'damper': damper, 'driver': driver, 'controller': controller, 'rate': float(rate),
             'lockstep': bool(lockstep)}
    recorders = int(record)
    sets = {k: corner_sets(v, k) for k, v in (('damper', damper), ('driver', driver))}
    nodes = full_car_nodes(modal, record)
    params = {}
    for exe, name, ns in nodes:
        if exe == 'recorder':
            p = {'output': str(bag), 'storage': storage, 'lockstep': bool(lockstep),
                 'namespaces': ','.join(c.CORNERS)}
        elif exe == 'full_car_plant':
            p = dict(model, vehicle=vehicle, road=road, duration=float(duration),
                     exit_at_end=True, expect_subscribers=1 + recorders,
                     body_imu_subscribers=int(modal) + recorders)
        elif exe == 'modal_controller':
            p = dict(model, vehicle=vehicle, recorders=recorders)
        else:
            i = c.CORNERS.index(ns)
            p = dict(model, vehicle=corner_vehicle(vehicle, ns), recorders=recorders,
                     damper=sets['damper'][i], driver=sets['driver'][i])
        if coupling_delay is not None and exe in ('full_car_plant', 'actuator'):
            p['coupling_delay'] = int(coupling_delay)
        label = _label(name, ns)
        p['stats_file'] = str(out / f'stats_{label.replace("/", "_")}.json')
        p.update((extra or {}).get(exe, {}))
        p.update((extra or {}).get(label, {}))
        params[label] = p
    param_file = out / 'params.yaml'
    with open(param_file, 'w', encoding='utf-8') as fh:
        yaml.safe_dump({'/' + label: {'ros__parameters': p} for label, p in params.items()},
                       fh)
    labels = [_label(name, ns) for _, name, ns in nodes]
    codes, stats, wall = _launch(out, _process_nodes(nodes, composed, modal), param_file,
                                 'full_car_plant', FULL_CAR_STOP_ORDER, domain_id,
                                 timeout if timeout is not None else 90.0 + 60.0 * duration,
                                 stats_labels=labels if composed else ())
    result = {'bag': str(bag) if record else None, 'returncodes': codes, 'stats': stats,
              'wall_s': wall, 'modal': bool(modal)}
    from mr_suspension.control.modal import ModalParams
    gain_names = {'law'} | {f.name for f in fields(ModalParams) if f.metadata.get('range')}
    gains = {k: v for k, v in (extra or {}).get('modal_controller', {}).items()
             if k in gain_names}
    config = full_car_config(vehicle, damper, driver, controller, rate,
                             modal=ModalParams(**gains) if modal else None)
    result['offline'] = full_car_offline(config, road, duration)
    if record:
        result['summary'] = full_car_bag_summary(bag, config.car.front.g)
        result['agreement'] = agreement(result['summary'], result['offline'])
    return result
