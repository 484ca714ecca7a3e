"""The topic contract, the nodes and the recorder agree (names, types, QoS, publishers)."""

import os

from mr_suspension.nodes import contract as c
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
    for name, topic in c.TOPICS.items():
        assert name == c.CLOCK or not name.startswith('/'), name
        assert topic.type.split('/')[0] in ('std_msgs', 'sensor_msgs', 'rosgraph_msgs')


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
            full = {t: node.resolve_topic_name(t) for t in c.TOPICS}
            pubs = {p.topic_name: p for p in node.publishers if p.topic_name not in AUTO}
            subs = {}
            for sub in node.subscriptions:
                if sub.topic_name not in AUTO:
                    subs.setdefault(sub.topic_name, []).append(sub)
            assert sorted(pubs) == sorted(full[t] for t in c.published_by(name)), name
            assert sorted(subs) == sorted(full[t] for t in c.subscribed_by(name)), name
            for t in c.published_by(name):
                pub = pubs[full[t]]
                assert _type_name(pub.msg_type) == c.TOPICS[t].type
                assert pub.qos_profile.depth == c.TOPICS[t].depth
            for t in c.subscribed_by(name):
                # (the recorder's time source adds its own /clock subscription)
                assert any(_type_name(sub.msg_type) == c.TOPICS[t].type
                           and sub.qos_profile.depth == c.TOPICS[t].depth
                           for sub in subs[full[t]]), (name, t)
        recorded = set(made['recorder'].counts)
        assert recorded == {made['recorder'].resolve_topic_name(t) for t in c.TOPICS}
    assert os.path.isdir(tmp_path / 'bag')
