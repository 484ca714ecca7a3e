"""The topic contract, the nodes and the recorder agree (names, types, QoS, publishers)."""

import os

import pytest

from mr_suspension.nodes import contract as c, recorder
from mr_suspension.nodes.actuator import ActuatorNode
from mr_suspension.nodes.controller import ControllerNode
from mr_suspension.nodes.plant import PlantNode
from mr_suspension.nodes.recorder import RecorderNode
from mr_suspension.nodes.testing import add, params, ros_context

AUTO = {'/rosout', '/parameter_events'}


def _type_name(cls):
    return cls.__module__.split('.')[0] + '/msg/' + cls.__name__


def test_yaml_and_module_agree():
    assert c.check_against_yaml() == []


def test_names_relative_and_types_standard():
    for name, topic in c.ALL_TOPICS.items():
        assert name in (c.CLOCK, c.DIAGNOSTICS) or not name.startswith('/'), name
        assert topic.type.split('/')[0] in ('std_msgs', 'sensor_msgs', 'rosgraph_msgs',
                                            'diagnostic_msgs')


def test_nodes_and_recorder_follow_contract(tmp_path):
    ns = '/front_left'
    lock = params(lockstep=True)
    with ros_context() as (ctx, ex, nodes):
        made = {
            'plant': add(ex, nodes, PlantNode(context=ctx, namespace=ns,
                                              parameter_overrides=params(lockstep=True))),
            'controller': add(ex, nodes, ControllerNode(context=ctx, namespace=ns,
                                                        parameter_overrides=lock)),
            'actuator': add(ex, nodes, ActuatorNode(context=ctx, namespace=ns,
                                                    parameter_overrides=lock)),
            'recorder': add(ex, nodes, RecorderNode(
                context=ctx, namespace=ns, parameter_overrides=params(
                    output=str(tmp_path / 'bag'), lockstep=True))),
        }
        for name, node in made.items():
            full = {t: node.resolve_topic_name(t) for t in c.ALL_TOPICS}
            pubs = {p.topic_name: p for p in node.publishers if p.topic_name not in AUTO}
            subs = {}
            # (the recorder's subscriptions sit on its internal, polled taps node)
            for sub in getattr(node, 'taps', node).subscriptions:
                if sub.topic_name not in AUTO:
                    subs.setdefault(sub.topic_name, []).append(sub)
            pub_names = c.published_by(name, scope='corner')
            sub_names = c.subscribed_by(name, scope='corner')
            assert sorted(pubs) == sorted(full[t] for t in pub_names), name
            assert {full[t] for t in sub_names} <= set(subs), name
            assert set(subs) <= {full[t] for t in c.subscribed_by(name, optional=True)}, name
            for t in pub_names:
                pub = pubs[full[t]]
                assert _type_name(pub.msg_type) == c.ALL_TOPICS[t].type
                assert pub.qos_profile.depth == c.ALL_TOPICS[t].depth
            for t in sub_names:
                # (the recorder's time source adds its own /clock subscription; in lock-step
                # its queues are deeper, the loop running faster than real time)
                depth = c.TOPICS[t].depth * (recorder.LOCKSTEP_QUEUE_FACTOR
                                             if name == 'recorder' else 1)
                assert any(_type_name(sub.msg_type) == c.TOPICS[t].type
                           and sub.qos_profile.depth == depth
                           for sub in subs[full[t]]), (name, t)
        recorded = set(made['recorder'].counts)
        assert recorded == {made['recorder'].resolve_topic_name(t) for t in c.TOPICS}
    assert os.path.isdir(tmp_path / 'bag')


@pytest.mark.parametrize('controller,damper,feedback,subscribed', [
    ('skyhook_onoff', 'spencer_bouc_wen', 'auto', False),  # on-off: never reads the field
    ('skyhook', 'rd1005_bingham', 'auto', False),  # inverts a model without state
    ('skyhook', 'spencer_bouc_wen', 'auto', True),  # Bouc-Wen state follows the current
    ('skyhook_onoff', 'rd1005_bingham', 'on', True),
    ('clipped_optimal', 'spencer_bouc_wen', 'off', False),
])
def test_controller_subscribes_to_coil_current_when_its_law_reads_it(
        controller, damper, feedback, subscribed):
    assert 'controller' in c.TOPICS[c.COIL_CURRENT].optional_subscribers
    with ros_context() as (ctx, ex, nodes):
        node = add(ex, nodes, ControllerNode(
            context=ctx, namespace='/fl', parameter_overrides=params(
                controller=controller, damper=damper, coil_feedback=feedback)))
        topics = {s.topic_name for s in node.subscriptions}
        assert ('/fl/' + c.COIL_CURRENT in topics) == subscribed


def test_controller_rejects_unknown_coil_feedback():
    with ros_context() as (ctx, _, _):
        with pytest.raises(ValueError, match='coil_feedback'):
            ControllerNode(context=ctx, parameter_overrides=params(coil_feedback='maybe'))


def test_full_car_nodes_follow_contract(tmp_path):
    """Full-car plant, modal controller and the recorder of all corners in the car namespace.

    Each corner topic under ``/<corner>/``, the car topics (``body/imu``) and the absolute ones
    once; types and depths as the contract says.
    """
    from mr_suspension.nodes.full_car_plant import FullCarPlantNode
    from mr_suspension.nodes.modal_controller import ModalControllerNode

    def expand(names):
        out = set()
        for t in names:
            if t in c.ABSOLUTE:
                out.add(t)
            elif c.ALL_TOPICS[t].scope == 'car':
                out.add('/' + t)
            else:
                out |= {f'/{corner}/{t}' for corner in c.CORNERS}
        return out

    def contract_name(full):
        if full in c.ABSOLUTE:
            return full
        first, _, rest = full.lstrip('/').partition('/')
        return rest if first in c.CORNERS else full.lstrip('/')

    lock = params(lockstep=True)
    with ros_context() as (ctx, ex, nodes):
        made = {
            'full_car_plant': add(ex, nodes, FullCarPlantNode(context=ctx,
                                                              parameter_overrides=lock)),
            'modal_controller': add(ex, nodes, ModalControllerNode(
                context=ctx, parameter_overrides=params(lockstep=True, coil_feedback='on'))),
            'recorder': add(ex, nodes, RecorderNode(context=ctx, parameter_overrides=params(
                output=str(tmp_path / 'bag'), lockstep=True,
                namespaces=','.join(c.CORNERS)))),
        }
        for name, node in made.items():
            pubs = {p.topic_name: p for p in node.publishers if p.topic_name not in AUTO}
            subs = {}
            for sub in getattr(node, 'taps', node).subscriptions:
                if sub.topic_name not in AUTO:
                    subs.setdefault(sub.topic_name, []).append(sub)
            assert set(pubs) == expand(c.published_by(name)), name
            assert expand(c.subscribed_by(name)) <= set(subs), name
            assert set(subs) <= expand(c.subscribed_by(name, optional=True)), name
            for full, pub in pubs.items():
                t = c.ALL_TOPICS[contract_name(full)]
                assert _type_name(pub.msg_type) == t.type and pub.qos_profile.depth == t.depth
            factor = recorder.LOCKSTEP_QUEUE_FACTOR if name == 'recorder' else 1
            for full, group in subs.items():
                t = c.ALL_TOPICS[contract_name(full)]
                assert any(_type_name(s.msg_type) == t.type and s.qos_profile.depth
                           == t.depth * factor for s in group), (name, full)
        assert set(made['recorder'].counts) == expand(list(c.TOPICS) + list(c.CAR_TOPICS))
        assert len(made['recorder'].counts) == 4 * (len(c.TOPICS) - 1) + 2
