"""``mr-suspension nodes --full-car --modal --composed``: one bag, equal to the offline simulator.

The composed full-car process (plant, modal controller, four actuators) and the recorder of all
corners as separate processes, lock-step; the figures read back from the bag. (The set of ten
processes starts the same nodes; it takes minutes to start on a small machine, so it is run by
``benchmarks/bench_full_car.py`` and by hand, not here.)
"""

from mr_suspension.nodes import contract as c
from mr_suspension.nodes.cli import format_result
from mr_suspension.nodes.launch import run_full_car

ROAD = '{type: bump, height: 0.04, length: 1.0, speed: 10.0, t0: 0.1, side: left}'


def test_composed_modal_full_car_bag_equals_offline(tmp_path):
    res = run_full_car(tmp_path / 'run', duration=0.3, road=ROAD, modal=True, composed=True,
                       timeout=120.0, domain_id='random')
    assert res['returncodes'] == {'full_car_plant': 0, 'recorder': 0}
    counts = res['summary']['counts']
    # Every corner topic of every corner, the body IMU and /clock: one message per sample.
    expected = {f'/{corner}/{t}' for corner in c.CORNERS for t in c.TOPICS
                if t not in c.ABSOLUTE} | {'/' + c.BODY_IMU, c.CLOCK}
    assert set(counts) == expected
    assert set(counts.values()) == {301}
    assert res['stats']['full_car_plant']['completed']
    for key, diff in res['agreement'].items():
        assert abs(diff) < 1e-6, (key, diff)
    text = format_result(res)
    assert 'modal controller' in text and 'RR dyn. tyre load RMS' in text
