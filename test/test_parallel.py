"""``mr_suspension.parallel``: serial and dask paths agree, and failures are clear and fast."""

import socket
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest

import mr_suspension
from mr_suspension import parallel


def _work(seed):
    """Deterministic, a bit of numpy: the same on every path."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(40, 40))
    return seed, float(np.linalg.norm(a @ a.T)), rng.integers(1000)


def _fails_on_three(x):
    if x == 3:
        raise ValueError('three is not allowed')
    return x * x


class _TwoArgError(Exception):
    def __init__(self, a, b):
        super().__init__(f'{a}/{b}')


def _fails_oddly(x):
    raise _TwoArgError(x, 'odd')


@pytest.fixture(scope='module')
def dask_client():
    """Yield a two-worker local cluster shared by the tests of this module."""
    with parallel.client(workers=2) as c:
        yield c


def _free_port():
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def test_serial_path_needs_no_dask():
    code = ('import sys; from mr_suspension import parallel; '
            'assert parallel.map_tasks(abs, [-1, 2]) == [1, 2]; '
            'assert not any(m == "dask" or m.startswith(("dask.", "distributed")) '
            'for m in sys.modules), "dask imported"')
    subprocess.run([sys.executable, '-c', code], check=True, timeout=60)


def test_two_workers_equal_serial_in_order(dask_client):
    items = list(range(12))
    serial = parallel.map_tasks(_work, items)
    assert [r[0] for r in serial] == items
    assert parallel.map_tasks(_work, items, dask_client=dask_client) == serial
    got = dict(parallel.iter_tasks(_work, items, dask_client=dask_client))
    assert [got[k] for k in items] == serial
    assert parallel.map_tasks(_work, [], dask_client=dask_client) == []


def test_own_local_cluster_and_scheduler_address(dask_client):
    items = [3, 1, 2]
    assert parallel.map_tasks(_work, items, workers=2) == [_work(i) for i in items]
    # the same cluster reached by its address (probe, worker and version checks)
    address = dask_client.scheduler.address
    assert parallel.map_tasks(_work, items, scheduler=address) == [_work(i) for i in items]


@pytest.mark.parametrize('path', ['serial', 'dask'])
def test_task_exception_names_the_item(path, dask_client):
    kw = {'dask_client': dask_client} if path == 'dask' else {}
    with pytest.raises(ValueError, match=r'^rec-c: three is not allowed$') as info:
        parallel.map_tasks(_fails_on_three, [1, 2, 3], names=['rec-a', 'rec-b', 'rec-c'], **kw)
    assert info.value.task == 'rec-c'
    # without names: the item's repr; a type that cannot be rebuilt becomes TaskError
    with pytest.raises(ValueError, match=r'item 1 \(3\): three'):
        parallel.map_tasks(_fails_on_three, [2, 3], **kw)
    with pytest.raises(parallel.TaskError, match=r'item 0 \(5\): _TwoArgError: 5/odd'):
        parallel.map_tasks(_fails_oddly, [5], **kw)
    # errors='return': the others still run
    out = dict(parallel.iter_tasks(_fails_on_three, [1, 3, 4], errors='return', **kw))
    assert out[0] == 1 and out[2] == 16 and isinstance(out[1], ValueError)


def test_unreachable_scheduler_is_a_clear_error_fast():
    t0 = time.monotonic()
    with pytest.raises(parallel.ParallelError, match='cannot reach dask scheduler'):
        parallel.map_tasks(abs, [1], scheduler=f'tcp://127.0.0.1:{_free_port()}', timeout=2.0)
    assert time.monotonic() - t0 < 2 * 2.0 + 5.0
    assert issubclass(parallel.ParallelError, OSError)  # the CLI reports it in one line


@pytest.mark.parametrize('address', ['localhost', 'udp://1.2.3.4:5', 'tcp://:8786',
                                     'tcp://host:70000'])
def test_bad_address(address):
    with pytest.raises(parallel.ParallelError, match='bad dask scheduler address'):
        parallel.map_tasks(abs, [1], scheduler=address)


def test_not_a_scheduler():
    """An HTTP server (the dashboard port, say) is refused quickly, not a hang or MemoryError."""
    srv = socket.socket()
    srv.bind(('127.0.0.1', 0))
    srv.listen(4)

    def answer():
        for _ in range(4):
            try:
                conn, _ = srv.accept()
            except OSError:
                return
            with conn:
                conn.sendall(b'HTTP/1.1 400 Bad Request\r\ncontent-length: 0\r\n\r\n')

    threading.Thread(target=answer, daemon=True).start()
    t0 = time.monotonic()
    try:
        with pytest.raises(parallel.ParallelError, match='dask'):
            parallel.map_tasks(abs, [1], scheduler=f'127.0.0.1:{srv.getsockname()[1]}',
                               timeout=3)
    finally:
        srv.close()
    assert time.monotonic() - t0 < 15.0


def test_scheduler_without_workers_and_version_mismatch(dask_client, monkeypatch):
    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=0, processes=False, dashboard_address=None,
                      scheduler_kwargs={'dashboard_address': '127.0.0.1:0'}) as empty:
        with pytest.raises(parallel.ParallelError, match='has no workers'):
            parallel.map_tasks(abs, [1], scheduler=empty.scheduler_address, timeout=1)
    monkeypatch.setattr(mr_suspension, '__version__', '0.0.0-other')
    with pytest.raises(parallel.ParallelError, match='same version'):
        parallel.map_tasks(abs, [1], scheduler=dask_client.scheduler.address)


def test_python_dash_c_is_quiet(tmp_path):
    """From ``python -c`` (spawned workers re-import no script): works, and dask says nothing."""
    code = textwrap.dedent("""
        from mr_suspension import parallel
        def f(x):
            if x == 2:
                raise KeyError('two')
            return -x
        with parallel.client(workers=2) as c:
            print(parallel.map_tasks(f, [0, 1], dask_client=c))
            out = dict(parallel.iter_tasks(f, [1, 2], dask_client=c, errors='return'))
        print(out[0], type(out[1]).__name__)
    """)
    p = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                       timeout=120, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert p.stdout.split('\n')[:2] == ['[0, -1]', '-1 KeyError']
    assert 'distributed' not in p.stderr and 'Traceback' not in p.stderr, p.stderr


def test_script_without_main_guard_gets_a_clear_error(tmp_path):
    script = tmp_path / 'sweep.py'
    script.write_text('from mr_suspension import parallel\n'
                      'print(parallel.map_tasks(abs, [-1], workers=1))\n')
    p = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                       timeout=120, cwd=tmp_path)
    assert p.returncode != 0
    assert 'ParallelError' in p.stderr and 'if __name__ == "__main__":' in p.stderr
    guarded = tmp_path / 'guarded.py'
    guarded.write_text('from mr_suspension import parallel\n'
                       'if __name__ == "__main__":\n'
                       '    print(parallel.map_tasks(abs, [-1, -2], workers=1))\n')
    p = subprocess.run([sys.executable, str(guarded)], capture_output=True, text=True,
                       timeout=120, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == '[1, 2]'


def test_default_workers():
    n = parallel.default_workers()
    assert n == 0 or n >= 2
    with pytest.raises(ValueError, match='workers'):
        parallel.map_tasks(abs, [1], workers=-1)
