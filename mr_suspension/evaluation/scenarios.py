"""Named road scenarios for the evaluation (seed 003 step and bump, ISO 8608, sine sweep).

Names: ``step`` (5 cm step, 10 ms rise, seed 003 §7.1), ``bump`` (5 cm, 2 m long (1 - cos)
bump at 10 m/s, seed 003 §7.2), ``iso_<class>_<speed>`` (ISO 8608 class A..H at a speed in
m/s, 20 s, fixed seed), ``sweep`` (5 mm exponential sine sweep 0.5-20 Hz in 40 s),
``harmonic_<freq>`` (1 cm sine, 10 s). Groups: ``iso`` (classes A-D at 10, 20 and 30 m/s),
``transient`` (step, bump), ``all`` (transient, iso and sweep), ``quick`` (step, bump,
iso_C_20).
"""

from dataclasses import dataclass

from mr_suspension.core import road as rd

ISO_CLASSES = ('A', 'B', 'C', 'D')
ISO_SPEEDS = (10.0, 20.0, 30.0)
ISO_DURATION = 20.0
STEP_HEIGHT = 0.05
BUMP_HEIGHT = 0.05


@dataclass(frozen=True)
class Scenario:
    """A road and the time of its event (for settling times)."""

    name: str
    road: rd.Road
    t_event: float = 0.0
    kind: str = 'random'


def _iso_names():
    return [f'iso_{c}_{int(v)}' for c in ISO_CLASSES for v in ISO_SPEEDS]


GROUPS = {
    'transient': ['step', 'bump'],
    'iso': _iso_names(),
    'quick': ['step', 'bump', 'iso_C_20'],
}
GROUPS['all'] = GROUPS['transient'] + GROUPS['iso'] + ['sweep']


def expand(names):
    """Expand group names and comma lists into scenario names (order kept, no duplicates)."""
    if isinstance(names, str):
        names = [names]
    out = []
    for item in names:
        for name in str(item).split(','):
            name = name.strip()
            if not name:
                continue
            for n in GROUPS.get(name, [name]):
                if n not in out:
                    out.append(n)
    if not out:
        raise ValueError('no scenario given')
    return out


def make(name, dt=1e-3, seed=1):
    """Build the scenario ``name`` (module doc) sampled at ``dt``."""
    if name == 'step':
        return Scenario(name, rd.step(STEP_HEIGHT, t0=0.5, rise=0.01, duration=10.0, dt=dt),
                        0.5, 'transient')
    if name == 'bump':
        return Scenario(name, rd.bump(BUMP_HEIGHT, length=2.0, speed=10.0, t0=0.5,
                                      duration=10.0, dt=dt), 0.5, 'transient')
    if name == 'sweep':
        return Scenario(name, rd.sweep(0.005, 0.5, 20.0, duration=40.0, dt=dt), 0.0, 'sweep')
    parts = name.split('_')
    try:
        if parts[0] == 'iso' and len(parts) == 3:
            speed = float(parts[2])
            road = rd.iso8608(parts[1].upper(), speed, duration=ISO_DURATION, dt=dt,
                              seed=seed + 17 * ISO_CLASSES.index(parts[1].upper())
                              if parts[1].upper() in ISO_CLASSES else seed)
            return Scenario(name, road, 0.0, 'random')
        if parts[0] == 'harmonic' and len(parts) == 2:
            return Scenario(name, rd.harmonic(0.01, float(parts[1]), duration=10.0, dt=dt),
                            0.0, 'harmonic')
    except ValueError as exc:
        raise ValueError(f'scenario {name!r}: {exc}') from None
    raise ValueError(f'unknown scenario {name!r}; use step, bump, sweep, iso_<A..H>_<speed>, '
                     f'harmonic_<freq> or a group {sorted(GROUPS)}')
