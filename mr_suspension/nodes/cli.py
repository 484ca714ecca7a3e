"""``mr-suspension nodes``: run the ROS 2 node set as processes, record a bag, summarise it."""

import json
from pathlib import Path
import shutil

import yaml

from mr_suspension.cli_common import road_spec_from_args as road_spec
from mr_suspension.nodes.launch import CORNER_TAGS, DEFAULT_ROAD, run_full_car, run_node_set

LABELS = {'body_acc_rms': ('body acc. RMS', 'm/s²', '.4f'),
          'working_space_rms': ('working space RMS', 'mm', '.3f'),
          'tyre_load_rms': ('dyn. tyre load RMS', 'N', '.2f')}


FULL_CAR_LABELS = {'heave_acc_rms': ('heave acc. RMS (CG)', 'm/s²', '.4f'),
                   'pitch_rate_rms': ('pitch rate RMS', 'rad/s', '.5f'),
                   'roll_rate_rms': ('roll rate RMS', 'rad/s', '.5f')}
FULL_CAR_LABELS.update({f'{key}_{tag}': (f'{tag.upper()} {label}', unit, fmt)
                        for tag in CORNER_TAGS for key, (label, unit, fmt) in LABELS.items()})


def format_result(res):
    """Readable summary of :func:`~mr_suspension.nodes.launch.run_node_set`'s result.

    Also of :func:`~mr_suspension.nodes.launch.run_full_car`'s (body and per-corner figures).
    """
    full = 'modal' in res
    plant = res['stats'].get('full_car_plant' if full else 'plant', {})
    mode = plant.get('mode', '?')
    what = ('full car, ' + ('modal controller' if res['modal'] else 'corner controllers')
            + ', ') if full else ''
    lines = [f'node set ({what}{mode}): bag {res["bag"]}', '',
             '| metric | node set (from bag) | offline simulator | difference |',
             '|---|---:|---:|---:|']
    for key, (label, unit, fmt) in (FULL_CAR_LABELS if full else LABELS).items():
        scale = 1e3 if unit == 'mm' else 1.0
        a = res['summary'][key] * scale
        b = res['offline'][key] * scale
        diff = res['agreement'].get(key)  # (none where the simulator gives 0)
        lines.append(f'| {label} [{unit}] | {a:{fmt}} | {b:{fmt}} | '
                     + ('-' if diff is None else f'{diff:+.3f} %') + ' |')
    counts = res['summary']['counts']
    lines += ['', f'messages in the bag: {sum(counts.values())} on {len(counts)} topics '
              f'({res["summary"]["samples"]} plant samples)']
    if plant:
        rate = plant.get('steps_per_s_sustained', 0)
        lines.append(f'plant: {plant.get("steps", 0)} steps at {rate:.0f} steps/s '
                     f'({rate / plant.get("rate", 1000):.2f}x real time) after a start-up '
                     f'handshake of {plant.get("startup_s", 0):.2f} s; force late on '
                     f'{plant.get("late_forces", 0)} steps; re-sends '
                     f'{plant.get("resends", 0)}; loop latency p50/p99 '
                     f'{1e3 * plant.get("latency_p50_s", 0):.2f}/'
                     f'{1e3 * plant.get("latency_p99_s", 0):.2f} ms')
    lines.append('process exit codes: ' + ', '.join(
        f'{k} {v}' for k, v in res['returncodes'].items()))
    return '\n'.join(lines)


def cmd_nodes(args):
    """Run the node set and print the summary read back from the bag."""
    out = Path(args.out)
    if out.exists() and args.overwrite:
        shutil.rmtree(out)
    if (args.modal or args.composed) and not args.full_car:
        raise SystemExit('mr-suspension nodes: --modal and --composed need --full-car')
    if args.full_car:
        spec = road_spec(args)
        if args.side != 'both' and spec.get('type') == 'bump' and not args.road_spec:
            spec = dict(spec, side=args.side)
        res = run_full_car(out, duration=args.duration,
                           road=yaml.safe_dump(spec, default_flow_style=True).strip(),
                           vehicle=args.vehicle or 'lisa_full_car', damper=args.damper,
                           driver=args.driver, controller=args.controller, modal=args.modal,
                           lockstep=not args.realtime, rate=args.rate, storage=args.storage,
                           coupling_delay=args.coupling_delay, composed=args.composed,
                           domain_id='random' if args.isolate else None)
    else:
        res = run_node_set(out, duration=args.duration, road=road_spec(args),
                           vehicle=args.vehicle or 'city_car', damper=args.damper,
                           driver=args.driver, controller=args.controller or 'skyhook_onoff',
                           lockstep=not args.realtime, rate=args.rate, storage=args.storage,
                           namespace=args.namespace, coupling_delay=args.coupling_delay,
                           domain_id='random' if args.isolate else None)
    text = format_result(res)
    (out / 'summary.md').write_text(text + '\n', encoding='utf-8')
    (out / 'result.json').write_text(json.dumps(res, indent=1, default=str), encoding='utf-8')
    print(text)
    print(f'wrote {out}/')
    return 0 if all(code == 0 for code in res['returncodes'].values()) else 1


def demo(out_dir):
    """Demo step: lock-step node set over the default bump, summary from the bag."""
    out = Path(out_dir)
    if out.exists():
        shutil.rmtree(out)
    res = run_node_set(out, duration=3.0, road=DEFAULT_ROAD)
    text = format_result(res)
    (out / 'summary.md').write_text(text + '\n', encoding='utf-8')
    print(text)
    print(f'wrote {out}/')
    return 0 if all(code == 0 for code in res['returncodes'].values()) else 1


def register(subparsers):
    """Add the ``nodes`` subcommand."""
    p = subparsers.add_parser(
        'nodes', help='run the ROS 2 node set with the recorder and summarise the bag',
        description='Start plant, controller, actuator and recorder as separate processes '
                    '(one namespace; with --full-car the full-car plant, four corner '
                    'controllers or the modal controller, four actuators in the corner '
                    'namespaces and one recorder), drive the road in lock-step (default) or '
                    'real time, close the rosbag2 bag cleanly and print a summary read back '
                    'from it next to the offline simulator.')
    p.add_argument('--out', default='out/nodes', help='output directory (bag, logs, stats)')
    p.add_argument('--overwrite', action='store_true', help='replace an existing --out')
    p.add_argument('--duration', type=float, default=3.0, help='road duration [s]')
    p.add_argument('--road', default='bump', choices=['step', 'bump', 'iso8608'],
                   help='road excitation (default: %(default)s)')
    p.add_argument('--road-spec', default='', help='road as a YAML mapping, e.g. '
                   '"{type: harmonic, amplitude: 0.01, freq: 1.5}" (overrides --road)')
    p.add_argument('--road-class', default='C', help='ISO 8608 class A..H (default: C)')
    p.add_argument('--speed', type=float, default=10.0, help='vehicle speed [m/s]')
    p.add_argument('--height', type=float, default=0.05, help='bump/step height [m]')
    p.add_argument('--seed', type=int, default=1, help='random road seed')
    p.add_argument('--vehicle', default=None,
                   help='config/vehicles set (default city_car; --full-car: lisa_full_car)')
    p.add_argument('--damper', default='rd1005_bingham',
                   help='config/dampers set (--full-car: also "front,rear" or four in corner '
                        'order)')
    p.add_argument('--driver', default='wonder_box',
                   help='config/drivers set (--full-car: also "front,rear" or four)')
    p.add_argument('--controller', default=None,
                   help='config/controllers set (default skyhook_onoff; --modal: skyhook, the '
                        "corners' estimation and inverse model)")
    p.add_argument('--rate', type=float, default=1000.0, help='node rate [Hz]')
    p.add_argument('--realtime', action='store_true',
                   help='real time instead of lock-step simulated time')
    p.add_argument('--coupling-delay', type=int, default=None,
                   help='lock-step: the plant applies each damper force this many samples '
                        'late (default 1, --full-car 0; 1: plant and actuators run '
                        "concurrently, faster; 0: the offline simulator's step order exactly)")
    p.add_argument('--storage', default='mcap', choices=['mcap', 'sqlite3'])
    p.add_argument('--namespace', default='front_left', help='corner namespace')
    p.add_argument('--full-car', action='store_true',
                   help='the full car: body and four corners (namespaces front_left, '
                        'front_right, rear_left, rear_right) into one bag, against the offline '
                        'full-car simulator')
    p.add_argument('--modal', action='store_true',
                   help='--full-car: the modal controller instead of four corner controllers')
    p.add_argument('--composed', action='store_true',
                   help='--full-car: plant, controllers and actuators in one process and one '
                        'executor (full_car_composed), the recorder in its own')
    p.add_argument('--side', default='left', choices=['left', 'right', 'both'],
                   help='--full-car, --road bump: the wheels that cross the bump '
                        '(default: %(default)s)')
    p.add_argument('--isolate', action='store_true',
                   help='run on a random ROS_DOMAIN_ID (1..100) instead of yours')
    p.set_defaults(func=cmd_nodes)
    return p
