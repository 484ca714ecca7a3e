"""Map independent tasks serially, on a local dask cluster, or on an existing one.

Sweeps, tuning and fleet diagnosis call :func:`map_tasks` (results in input order) or
:func:`iter_tasks` (results as they complete). ``workers=0`` (the default) is the serial path,
``workers=N`` starts a local ``dask.distributed`` cluster of N single-threaded worker processes
on 127.0.0.1, ``scheduler='tcp://host:8786'`` uses a running cluster (``dask scheduler`` and
``dask worker tcp://host:8786`` on the machines; see ``docs/parallel.md``). Results are
identical on every path (each task is a pure function of its item).

Hardening:

* dask is imported only when a cluster is asked for;
* a scheduler address is checked before a client is made: a malformed address, nothing
  listening, or something that is not a dask scheduler (a dashboard port, a worker) is a
  :class:`ParallelError` within ``timeout`` seconds (default 10), never a hang; so is a
  scheduler without workers (after waiting ``timeout`` for one) or workers whose
  ``mr_suspension`` version differs from ours (or that cannot import it);
* a task that raises is re-raised with its item's name in the message (same exception type
  when it can be rebuilt from one message, else :class:`TaskError`), on every path;
* dask's own logging is kept at ERROR (set ``MR_SUSPENSION_DEBUG=1`` for its INFO/WARNING);
* worker processes are *spawned*: they re-import the main script, so a script that starts a
  local cluster must do it under ``if __name__ == '__main__':``. Without that guard the worker
  stops with a one-line message and the script gets a :class:`ParallelError` saying so
  (``python -c``, the ``mr-suspension`` entry point and pytest are fine).
"""

import asyncio
import contextlib
import logging
import multiprocessing
import os
import sys
import threading

DEFAULT_TIMEOUT = 10.0  # [s] to reach a scheduler, and to wait for its first worker
DEBUG_ENV = 'MR_SUSPENSION_DEBUG'
GUARD_HINT = ('a local dask cluster was started while a worker process re-imported the main '
              'script: put the code that starts it under `if __name__ == "__main__":` '
              '(worker processes are spawned and re-import the main module)')


class ParallelError(OSError):
    """A cluster could not be reached or started (an environment problem, not the data)."""


class TaskError(RuntimeError):
    """A task failed and its exception could not be re-raised as its own type.

    ``task`` is the item's name, ``original`` the exception (``__cause__`` too).
    """

    def __init__(self, message, task=None, original=None):
        super().__init__(message)
        self.task = task
        self.original = original


def default_workers():
    """Local workers to start by default: the CPUs this process may use, 0 (serial) for one."""
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        n = os.cpu_count() or 1
    return n if n > 1 else 0


def _verbose():
    return bool(os.environ.get(DEBUG_ENV))


@contextlib.contextmanager
def _quiet_logs():
    """Keep the ``distributed`` loggers of this process at ERROR unless debugging."""
    if _verbose():
        yield
        return
    names = ('distributed', 'tornado', 'asyncio')
    loggers = [logging.getLogger(n) for n in names]
    old = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.ERROR)
    try:
        yield
    finally:
        for lg, level in zip(loggers, old):
            lg.setLevel(level)


def _bootstrapping():
    """Return True in a spawned process still importing the parent's main module."""
    return bool(getattr(multiprocessing.current_process(), '_inheriting', False))


def _one_line(exc):
    return ' '.join(str(exc).split()) or type(exc).__name__


def _probe(address, timeout):
    """Return the identity of the dask scheduler at ``address``; ParallelError if it is not one.

    Runs on its own thread and event loop, so it neither blocks forever nor needs the
    caller's loop (works from Jupyter too).
    """
    from distributed.comm import connect
    from distributed.core import send_recv

    async def ask():
        comm = await connect(address, timeout=timeout)
        try:
            return await asyncio.wait_for(send_recv(comm, op='identity'), timeout)
        finally:
            comm.abort()

    box = {}

    def run():
        try:
            box['value'] = asyncio.run(ask())
        except BaseException as exc:  # noqa: B902 - reported to the caller below
            box['error'] = exc

    th = threading.Thread(target=run, name='mr-suspension-dask-probe', daemon=True)
    th.start()
    th.join(2.0 * timeout + 5.0)
    hint = ('start one with `dask scheduler` (it listens on tcp://HOST:8786; the dashboard '
            'port 8787 is not the scheduler)')
    if th.is_alive():
        raise ParallelError(f'dask scheduler {address!r} did not answer within '
                            f'{2 * timeout + 5:g} s; {hint}')
    err = box.get('error')
    if err is not None:
        if isinstance(err, (OSError, asyncio.TimeoutError)):
            raise ParallelError(f'cannot reach dask scheduler {address!r} '
                                f'({_one_line(err)}); {hint}') from None
        raise ParallelError(f'{address!r} does not speak the dask protocol '
                            f'({type(err).__name__}: {_one_line(err)[:120]}); give the '
                            f'address of a dask scheduler: {hint}') from None
    ident = box.get('value')
    kind = ident.get('type') if isinstance(ident, dict) else None
    if kind != 'Scheduler':
        what = f'a dask {kind}' if kind else 'not a dask scheduler'
        raise ParallelError(f"{address!r} is {what}; give the scheduler's address "
                            '(tcp://HOST:8786, printed by `dask scheduler`)')
    return ident


def _check_address(address):
    from distributed.comm import registry
    from distributed.comm.addressing import parse_address, parse_host_port

    address = str(address).strip()
    if '://' not in address:
        address = 'tcp://' + address
    try:
        scheme, loc = parse_address(address, strict=True)
        registry.get_backend(scheme)
        if scheme in ('tcp', 'tls'):
            host, port = parse_host_port(loc)
            if not host:
                raise ValueError('no host')
            if not 0 < int(port) < 65536:
                raise ValueError(f'port {port} out of range')
    except (ValueError, TypeError) as exc:
        raise ParallelError(f'bad dask scheduler address {address!r} ({_one_line(exc)}); '
                            'expected tcp://HOST:PORT, e.g. tcp://10.0.0.5:8786') from None
    return address


def _package_version():
    import mr_suspension

    return getattr(mr_suspension, '__version__', 'unknown')


def _check_workers(c, timeout):
    """Wait for one worker; every worker must import our package at our version."""
    from mr_suspension import __version__ as ours

    try:
        c.wait_for_workers(1, timeout=timeout)
    except Exception:  # noqa: B902 - dask raises TimeoutError or its own types here
        raise ParallelError(f'dask scheduler {c.scheduler.address} has no workers (waited '
                            f'{timeout:g} s); start some with `dask worker '
                            f'{c.scheduler.address}`') from None
    try:
        got = c.run(_package_version, on_error='return')
    except Exception as exc:  # noqa: B902 - a worker that cannot unpickle our function
        got = {'?': exc}
    bad = {w: v for w, v in got.items() if v != ours}
    if bad:
        shown = '; '.join(f'{w}: {_one_line(v) if isinstance(v, BaseException) else v}'
                          for w, v in sorted(bad.items(), key=lambda kv: str(kv[0]))[:4])
        raise ParallelError(f'dask workers must run mr_suspension {ours} (the same '
                            f'version as this client); found {shown}. Install this '
                            "package version in every worker's environment")


def _close(obj):
    with contextlib.suppress(Exception):
        obj.close()


@contextlib.contextmanager
def client(workers=0, scheduler=None, timeout=DEFAULT_TIMEOUT):
    """Yield a ``dask.distributed.Client`` (or None for the serial path); close what we started.

    ``scheduler`` (an address) wins over ``workers``. Errors reaching or starting a cluster
    are :class:`ParallelError` (see the module docstring).
    """
    if not scheduler and not workers:
        yield None
        return
    if not scheduler and (int(workers) != workers or workers < 0):
        raise ValueError(f'workers must be an integer >= 0, got {workers}')
    if _bootstrapping():
        raise SystemExit(f'mr_suspension.parallel: {GUARD_HINT}')
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError as exc:  # pragma: no cover - dask is a pinned dependency
        raise ParallelError(f'dask.distributed is not installed: {exc}') from exc
    with _quiet_logs():
        level = logging.WARNING if _verbose() else logging.CRITICAL
        if scheduler:
            address = _check_address(scheduler)
            _probe(address, timeout)
            try:
                c = Client(address, timeout=f'{timeout}s', set_as_default=False)
            except Exception as exc:  # noqa: B902 - one clear error for every failure
                raise ParallelError(f'cannot connect to dask scheduler {address!r}: '
                                    f'{_one_line(exc)}') from None
            try:
                _check_workers(c, timeout)
                yield c
            finally:
                _close(c)
            return
        try:
            cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1,
                                   processes=True, host='127.0.0.1', scheduler_port=0,
                                   dashboard_address=None, silence_logs=level,
                                   # the scheduler's HTTP routes (no dashboard) on a free
                                   # local port, not on 0.0.0.0:8787
                                   scheduler_kwargs={'dashboard_address': '127.0.0.1:0'})
        except Exception as exc:  # noqa: B902 - one clear error for every failure
            main = sys.modules.get('__main__')
            hint = (f'; if {main.__file__} starts it at import, {GUARD_HINT}'
                    if getattr(main, '__file__', None) else '')
            raise ParallelError(f'cannot start a local dask cluster of {workers} workers '
                                f'({type(exc).__name__}: {_one_line(exc)}){hint}') from None
        try:
            c = Client(cluster, set_as_default=False)
        except Exception:
            _close(cluster)
            raise
        try:
            yield c
        finally:
            _close(c)
            _close(cluster)


def _name(item, index, names):
    if names is not None:
        return str(names[index])
    name = getattr(item, 'name', None)
    if isinstance(name, str) and name:
        return name
    text = repr(item)
    return f'item {index} ({text[:60] + "..." if len(text) > 60 else text})'


def named_error(exc, name):
    """Return ``exc`` as the same type with ``'<name>: '`` before its message (else TaskError).

    The returned exception has ``task`` (the name) and ``original`` attributes.
    """
    msg = f'{name}: {_one_line(exc)}'
    new = None
    if type(exc) is not TaskError:
        try:
            new = type(exc)(msg)
            if new.args != (msg,) or msg not in str(new):
                new = None
        except Exception:  # noqa: B902 - arbitrary constructors
            new = None
    if new is None:
        new = TaskError(f'{name}: {type(exc).__name__}: {_one_line(exc)}')
    with contextlib.suppress(Exception):
        new.task = name
        new.original = exc
    return new


def iter_tasks(fn, items, workers=0, scheduler=None, dask_client=None, names=None,
               errors='raise', timeout=DEFAULT_TIMEOUT):
    """Yield ``(index, fn(items[index]))`` as the tasks complete (in order when serial).

    ``errors='raise'`` re-raises a task's exception named after its item (see
    :func:`named_error`; ``names`` gives the names, else an item's ``name`` attribute or its
    repr); ``errors='return'`` yields that exception as the result instead, so one bad item
    does not stop the others. A worker that dies (killed, out of memory) is such an error
    too, after dask's retries. Unfinished tasks are cancelled when the caller stops.
    """
    if errors not in ('raise', 'return'):
        raise ValueError(f"errors must be 'raise' or 'return', got {errors!r}")
    items = list(items)
    if names is not None and len(names) != len(items):
        raise ValueError(f'{len(names)} names for {len(items)} items')
    if dask_client is not None:
        yield from _iter_dask(dask_client, fn, items, names, errors)
        return
    with client(workers, scheduler, timeout) as c:
        if c is not None:
            yield from _iter_dask(c, fn, items, names, errors)
            return
        for k, item in enumerate(items):
            try:
                out = fn(item)
            except Exception as exc:  # noqa: B902 - re-raised (or returned) with its name
                err = named_error(exc, _name(item, k, names))
                if errors == 'raise':
                    raise err from exc
                out = err
            yield k, out


def _iter_dask(c, fn, items, names, errors):
    if not items:
        return
    from dask.distributed import as_completed

    with _quiet_logs():
        futures = c.map(fn, items, pure=False)
        index = {f.key: k for k, f in enumerate(futures)}
        pending = set(index)
        try:
            for fut in as_completed(futures, loop=c.loop):
                k = index[fut.key]
                try:
                    out = fut.result()
                except Exception as exc:  # noqa: B902 - re-raised (or returned) with its name
                    err = named_error(exc, _name(items[k], k, names))
                    if errors == 'raise':
                        raise err from exc
                    out = err
                pending.discard(fut.key)
                fut.release()
                yield k, out
        finally:
            left = [f for f in futures if f.key in pending]
            if left:
                with contextlib.suppress(Exception):
                    c.cancel(left)


def map_tasks(fn, items, workers=0, scheduler=None, dask_client=None, names=None,
              timeout=DEFAULT_TIMEOUT):
    """Return ``[fn(item) for item in items]``, computed serially or on dask.

    ``dask_client`` reuses an open client (from :func:`client`) across several maps; otherwise a
    client is opened for this call from ``workers`` / ``scheduler``. ``fn`` must be picklable
    (a module-level function or a ``functools.partial`` of one). The first failing task (in
    completion order) is re-raised with its item's name (:func:`named_error`).
    """
    items = list(items)
    out = [None] * len(items)
    for k, value in iter_tasks(fn, items, workers, scheduler, dask_client, names, 'raise',
                               timeout):
        out[k] = value
    return out
