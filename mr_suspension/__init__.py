"""mr_suspension: semi-active MR-damper quarter-car suspension for ROS 2."""

import hashlib
import os
from pathlib import Path
import shutil
import sys
import tempfile

__version__ = '0.1.0'


def _use_versioned_numba_cache():
    """Point numba's on-disk cache at a folder named by a hash of this package's sources.

    numba re-validates a cached kernel only against its own file, so a kernel that calls a
    jitted function from another module (the simulator calling the control laws and damper
    laws) would silently keep the old code after an edit. Keying the cache folder on every
    source file makes any edit start a fresh cache. ``NUMBA_CACHE_DIR`` set by the user wins.
    """
    if os.environ.get('NUMBA_CACHE_DIR'):
        return
    root = Path(__file__).resolve().parent
    digest = hashlib.sha1()
    for path in sorted(root.rglob('*.py')):
        digest.update(path.relative_to(root).as_posix().encode())
        digest.update(path.read_bytes())
    base = Path(os.environ.get('XDG_CACHE_HOME') or Path.home() / '.cache') / 'mr_suspension'
    target = base / f'numba-{digest.hexdigest()[:16]}'
    try:
        target.mkdir(parents=True, exist_ok=True)
        old = sorted(base.glob('numba-*'), key=lambda p: p.stat().st_mtime)[:-4]
        for stale in old:  # keep the few most recent versions
            if stale != target:
                shutil.rmtree(stale, ignore_errors=True)
    except OSError:
        target = Path(tempfile.gettempdir()) / f'mr_suspension-numba-{digest.hexdigest()[:16]}'
    os.environ['NUMBA_CACHE_DIR'] = str(target)
    if 'numba' in sys.modules:  # imported before us: update its live configuration too
        sys.modules['numba'].config.CACHE_DIR = str(target)


_use_versioned_numba_cache()
