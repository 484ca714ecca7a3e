"""The launch files start what ``mr-suspension nodes`` starts, as the contract names it.

``launch`` and ``launch_ros`` are not installable here, so the files are read, not imported:
every ``Node(...)`` (loops over ``CORNERS`` unrolled) with its package, executable, name,
namespace, parameter file, parameter overrides and condition.
"""

import ast
import importlib

import pytest
import yaml

from mr_suspension.nodes import contract as c
from mr_suspension.nodes.launch import corner_nodes, full_car_nodes

ARG = 'arg'  # marker of a LaunchConfiguration


class LaunchFile:
    """The ``Node`` actions and launch arguments of a launch file, read with ``ast``."""

    def __init__(self, path):
        self.tree = ast.parse(path.read_text(encoding='utf-8'), str(path))
        self.constants = {}
        for stmt in self.tree.body:
            if isinstance(stmt, ast.Assign) and len(stmt.targets) == 1 \
                    and isinstance(stmt.targets[0], ast.Name):
                try:
                    self.constants[stmt.targets[0].id] = ast.literal_eval(stmt.value)
                except ValueError:
                    pass
        self.nodes, self.arguments = [], {}
        func = next(f for f in self.tree.body if isinstance(f, ast.FunctionDef)
                    and f.name == 'generate_launch_description')
        self.locals = {}
        self._walk(func.body, {})

    def _walk(self, body, env):
        for stmt in body:
            if isinstance(stmt, ast.For):
                for value in self.value(stmt.iter, env):
                    self._walk(stmt.body, dict(env, **{stmt.target.id: value}))
                continue
            if isinstance(stmt, ast.Assign) and isinstance(stmt.targets[0], ast.Name):
                self.locals[stmt.targets[0].id] = stmt.value
            for call in ast.walk(stmt):
                if isinstance(call, ast.Call) and isinstance(call.func, ast.Name):
                    if call.func.id == 'Node':
                        self.nodes.append({k.arg: self.value(k.value, env)
                                           for k in call.keywords})
                    elif call.func.id == 'DeclareLaunchArgument':
                        name = self.value(call.args[0], env)
                        self.arguments[name] = {k.arg: self.value(k.value, env)
                                                for k in call.keywords}

    def value(self, node, env):
        """Evaluate the small subset of Python the launch files use."""
        if isinstance(node, ast.Constant):
            return node.value
        if isinstance(node, ast.Name):
            if node.id in env:
                return env[node.id]
            if node.id in self.constants:
                return self.constants[node.id]
            if node.id in self.locals:
                return self.value(self.locals[node.id], env)
            raise AssertionError(f'unknown name {node.id}')
        if isinstance(node, (ast.List, ast.Tuple)):
            return [self.value(e, env) for e in node.elts]
        if isinstance(node, ast.Dict):
            return {self.value(k, env): self.value(v, env)
                    for k, v in zip(node.keys, node.values)}
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
            return self.value(node.left, env) + self.value(node.right, env)
        if isinstance(node, ast.Call):
            func = node.func.id if isinstance(node.func, ast.Name) else node.func.attr
            args = [self.value(a, env) for a in node.args]
            if func == 'LaunchConfiguration':
                return (ARG, args[0])
            if func == 'parameter_file':
                return ('file', args[0])
            if func in ('IfCondition', 'UnlessCondition'):
                return (func, args[0])
            if func in ('ParameterValue', 'PythonExpression'):
                return (func, args[0])
            if func == 'join':
                return self.value(node.func.value, env).join(args[0])
        raise AssertionError(f'cannot evaluate {ast.dump(node)}')

    def started(self, **arguments):
        """Return ``(executable, name, namespace)`` of the nodes these arguments start."""
        values = {k: str(v.get('default_value')) for k, v in self.arguments.items()}
        values.update({k: str(v).lower() for k, v in arguments.items()})
        out = []
        for node in self.nodes:
            cond = node.get('condition')
            if cond is not None:
                kind, (_, arg) = cond
                if (values[arg] == 'true') != (kind == 'IfCondition'):
                    continue
            ns = node.get('namespace', '')
            if isinstance(ns, tuple):
                ns = values[ns[1]]
            out.append((node['executable'], node['name'], ns))
        return sorted(out)


@pytest.fixture(scope='module')
def files(repo_root):
    return {name: LaunchFile(repo_root / 'launch' / f'{name}.launch.py')
            for name in ('corner', 'full_car')}


def _setup_nodes(repo_root):
    tree = ast.parse((repo_root / 'setup.py').read_text(encoding='utf-8'))
    nodes = next(ast.literal_eval(s.value) for s in tree.body if isinstance(s, ast.Assign)
                 and getattr(s.targets[0], 'id', '') == 'NODES')
    installs_launch = any(isinstance(n, ast.Constant) and n.value == 'launch/*.launch.py'
                          for n in ast.walk(tree))
    return nodes, installs_launch


@pytest.mark.parametrize('modal', [False, True])
@pytest.mark.parametrize('record', [True, False])
def test_launch_files_start_what_the_runner_starts(files, modal, record):
    assert files['full_car'].started(modal=modal, record=record) == \
        sorted(full_car_nodes(modal, record))
    assert files['corner'].started(record=record) == sorted(corner_nodes('front_left', record))
    assert files['corner'].started(record=record, namespace='rear_right') == \
        sorted(corner_nodes('rear_right', record))


def test_launch_nodes_follow_the_contract_and_their_parameter_files(files, repo_root):
    setup_nodes, installs_launch = _setup_nodes(repo_root)
    assert installs_launch
    assert {'full_car_plant', 'modal_controller'} <= set(setup_nodes)
    assert tuple(files['full_car'].constants['CORNERS']) == c.CORNERS
    contract_nodes = {n for t in c.ALL_TOPICS.values()
                      for n in t.publishers + t.subscribers + t.optional_subscribers}
    for launch in files.values():
        assert launch.nodes
        for node in launch.nodes:
            exe = node['executable']
            assert node['package'] == 'mr_suspension'
            assert exe in setup_nodes
            module = importlib.import_module(f'mr_suspension.nodes.{exe}')
            assert callable(module.main) and module.NODE == node['name'] == exe
            assert exe in contract_nodes
            ns = node.get('namespace', '')
            # The car's nodes (full-car plant, modal controller, the recorder of all corners)
            # sit in the car's namespace; a corner's in the corner's.
            if launch is files['full_car']:
                car_level = any(c.ALL_TOPICS[t].scope == 'car'
                                for t in c.published_by(exe) + c.subscribed_by(exe))
                assert (ns == '') == car_level, (exe, ns)
                assert ns == '' or ns in c.CORNERS
            params = node['parameters']
            assert params[0] == ('file', exe)
            path = repo_root / 'config' / 'nodes' / f'{exe}.yaml'
            declared = yaml.safe_load(path.read_text(encoding='utf-8'))[f'/**/{exe}'][
                'ros__parameters']
            for key in params[1]:
                assert key in declared, (exe, key)


def test_launch_defaults_parse(files):
    from mr_suspension.nodes.plant import parse_road
    for launch in files.values():
        args = launch.arguments
        for key in ('lockstep', 'record'):
            assert args[key]['default_value'] in ('true', 'false')
        assert parse_road(args['road']['default_value'])['type'] == 'bump'
        float(args['duration']['default_value'])
    assert files['full_car'].arguments['vehicle']['default_value'] == 'lisa_full_car'


@pytest.mark.parametrize('modal', [False, True])
def test_runner_parameters(tmp_path, monkeypatch, repo_root, modal):
    """``mr-suspension nodes --full-car`` gives every node its namespace and parameters."""
    from mr_suspension.nodes import launch

    class Started(Exception):
        pass

    def fake_launch(out, nodes, param_file, plant, stop_order, domain_id, limit, **kw):
        raise Started(nodes, param_file)

    monkeypatch.setattr(launch, '_launch', fake_launch)
    with pytest.raises(Started) as info:
        launch.run_full_car(tmp_path / 'run', duration=0.5, modal=modal)
    nodes, param_file = info.value.args
    assert nodes == full_car_nodes(modal)
    data = yaml.safe_load(param_file.read_text(encoding='utf-8'))
    assert sorted(data) == sorted('/' + (f'{ns}/{name}' if ns else name)
                                  for _, name, ns in nodes)
    p = {k: v['ros__parameters'] for k, v in data.items()}
    assert p['/recorder']['namespaces'].split(',') == list(c.CORNERS)
    assert p['/full_car_plant']['body_imu_subscribers'] == int(modal) + 1
    assert p['/full_car_plant']['expect_subscribers'] == 2
    assert p['/full_car_plant']['coupling_delay'] == 0  # lock-step: the simulator's order
    for corner in c.CORNERS:
        assert p[f'/{corner}/actuator']['vehicle'] == f'lisa_full_car:{corner}'
        assert p[f'/{corner}/actuator']['coupling_delay'] == 0
        assert (f'/{corner}/controller' in p) != modal
    if modal:
        assert p['/modal_controller']['controller'] == 'skyhook'
    for label, values in p.items():
        exe = label.rpartition('/')[2]
        path = repo_root / 'config' / 'nodes' / f'{exe}.yaml'
        declared = yaml.safe_load(path.read_text(encoding='utf-8'))[f'/**/{exe}']
        assert set(values) <= set(declared['ros__parameters']), label
