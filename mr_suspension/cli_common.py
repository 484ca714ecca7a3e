"""Helpers shared by the command lines of the package: options, output folders, one-line errors.

The package CLI (:mod:`mr_suspension.cli`) and the subcommands that the other parts register
(``identification.cli``, ``evaluation.cli``, ``evaluation.tune_cli``, ``nodes.cli``) all build
on these; this module imports none of them.
"""

import math
import os
from pathlib import Path
import sys
import warnings

import yaml

DEBUG_ENV = 'MR_SUSPENSION_DEBUG'  # set to 1 for tracebacks instead of one-line errors


def road_spec_from_args(args):
    """Return the road mapping of the ``--road ...`` options (``--road-spec`` wins if given)."""
    if getattr(args, 'road_spec', ''):
        try:
            spec = yaml.safe_load(args.road_spec)
        except yaml.YAMLError:
            spec = None
        if not isinstance(spec, dict):
            raise ValueError('--road-spec must be a YAML mapping such as "{type: step}"')
        return spec
    spec = {'type': args.road}
    if args.road == 'iso8608':
        spec.update(road_class=args.road_class, speed=args.speed, seed=args.seed)
    elif args.road == 'bump':
        spec.update(height=args.height, speed=args.speed)
    elif args.road == 'step':
        spec.update(height=args.height)
    elif args.road == 'harmonic':
        spec.update(amplitude=args.height, freq=args.freq)
    elif args.road == 'sweep':
        spec.update(amplitude=args.height)
    return spec


def add_plant_arguments(parser):
    """Add ``--vehicle``, ``--damper`` and ``--driver`` (the corner of ``sim.corner``)."""
    parser.add_argument('--vehicle', default='city_car',
                        help='config/vehicles name or YAML path (default: %(default)s)')
    parser.add_argument('--damper', default='rd1005_bingham',
                        help='config/dampers name, YAML path or a model.json fitted by '
                             'diagnose (default: %(default)s)')
    parser.add_argument('--driver', default='wonder_box',
                        help='config/drivers name or YAML path (default: %(default)s)')


def output_dir(path, option='--out'):
    """Create (if needed) and return the output directory ``path``; clear error if it cannot be.

    An existing file, a path through a file or an unwritable place raise ValueError.
    """
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise ValueError(f'{option} {out} is an existing file, not a directory; give a '
                         'directory path (it is created if missing)')
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f'cannot create the {option} directory {out} ({exc.strerror}); '
                         'choose a writable place') from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise ValueError(f'{option} directory {out} is not writable; choose a writable place')
    return out


def check_numbers(args):
    """Reject NaN or infinite float options (argparse's ``float`` accepts them)."""
    for name, value in vars(args).items():
        if isinstance(value, float) and not math.isfinite(value):
            option = '--' + name.replace('_', '-')
            raise ValueError(f'{option} must be a finite number, got {value}')


def _one_line(exc):
    """Return the message of ``exc`` on one line."""
    if isinstance(exc, OSError) and exc.strerror:
        where = f' {exc.filename}' if exc.filename else ''
        return f'{exc.strerror}:{where}; check the path and its permissions'
    text = ' '.join(str(exc).split()) or type(exc).__name__
    if isinstance(exc, KeyError):
        text = f'missing key {text}'
    return text


def _expected_errors():
    """Exception types that mean bad input (reported as ``error: ...``, exit code 2)."""
    types = [ValueError, OSError, yaml.YAMLError, MemoryError]
    try:  # unreadable bags (the readers' own error types)
        from mcap.exceptions import McapError
        from rosbags.highlevel import AnyReaderError
        from rosbags.rosbag2 import ReaderError
        types += [McapError, AnyReaderError, ReaderError]
    except ImportError:
        pass
    return tuple(types)


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """Print a Python warning as one ``warning: ...`` line on stderr."""
    print(f'warning: {" ".join(str(message).split())}', file=sys.stderr)


def run_command(args, prog='mr-suspension'):
    """Run ``args.func(args)`` and turn errors into one line on stderr.

    Bad input (ValueError, OSError, YAML errors, ...) prints ``<prog> <command>: error: ...``
    and returns 2; an unexpected exception prints one line asking for a report and returns 1
    (the traceback only with ``MR_SUSPENSION_DEBUG=1``). Warnings print as ``warning: ...``.
    """
    label = f'{prog} {getattr(args, "command", "") or ""}'.strip()
    with warnings.catch_warnings():
        warnings.showwarning = _show_warning
        try:
            check_numbers(args)
            code = args.func(args)
            return 0 if code is None else int(code)  # commands return an exit code
        except KeyboardInterrupt:
            print(f'{label}: interrupted', file=sys.stderr)
            return 130
        except _expected_errors() as exc:
            if os.environ.get(DEBUG_ENV):
                raise
            print(f'{label}: error: {_one_line(exc)}', file=sys.stderr)
            return 2
        except Exception as exc:  # noqa: B902 - last resort: one line instead of a traceback
            if os.environ.get(DEBUG_ENV):
                raise
            print(f'{label}: error: internal error ({type(exc).__name__}: {_one_line(exc)}); '
                  f'please report it with the command line (set {DEBUG_ENV}=1 for the '
                  'traceback)', file=sys.stderr)
            return 1
