"""The package's layers: imports run downward only, and no module imports itself back.

Read from the source (every ``import`` statement, also inside functions), not by importing.
"""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / 'mr_suspension'

# Lowest first. A unit imports from itself or from a strictly lower layer only.
LAYERS = (
    ('__init__',),
    ('core', 'bagtools', 'plots', 'cli_common', 'parallel'),
    ('control',),
    ('sim',),
    ('truth', 'identification', 'evaluation'),
    ('nodes',),
    ('cli',),
)
LEVEL = {unit: i for i, units in enumerate(LAYERS) for unit in units}


def _module(path):
    parts = path.relative_to(PACKAGE.parent).with_suffix('').parts
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


def _unit(module):
    parts = module.split('.')
    return parts[1] if len(parts) > 1 else '__init__'


def _imports(path, modules):
    """Modules of the package that ``path`` imports (a name imported from a package counts)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [f'{node.module}.{a.name}' if f'{node.module}.{a.name}' in modules
                     else node.module for a in node.names]
        else:
            continue
        out.update(n for n in names if n.split('.')[0] == 'mr_suspension')
    return out


def _graph():
    paths = sorted(PACKAGE.rglob('*.py'))
    modules = {_module(p) for p in paths}
    return {_module(p): _imports(p, modules) - {_module(p)} for p in paths}


def test_every_unit_has_a_layer():
    units = {_unit(m) for m in _graph()}
    assert units <= set(LEVEL), f'units without a layer: {sorted(units - set(LEVEL))}'


def test_imports_run_downward():
    up = [f'{a} imports {b}' for a, deps in _graph().items() for b in deps
          if _unit(a) != _unit(b) and LEVEL[_unit(b)] >= LEVEL[_unit(a)]]
    assert not up, '\n'.join(sorted(up))


def test_no_module_imports_itself_back():
    graph = _graph()
    state, cycles = {}, []

    def visit(m, stack):
        state[m] = 1
        for d in sorted(graph.get(m, ())):
            if state.get(d) == 1:
                cycles.append(' -> '.join(stack[stack.index(d):] + [d]))
            elif d in graph and d not in state:
                visit(d, stack + [d])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    assert not cycles, '\n'.join(cycles)


def test_the_rule_sees_an_upward_import(tmp_path):
    """The reader finds an import inside a function (the form an upward import hides in)."""
    f = tmp_path / 'x.py'
    f.write_text('def g():\n    from mr_suspension.cli import main\n    return main\n')
    assert _imports(f, {'mr_suspension.cli'}) == {'mr_suspension.cli'}
