"""
The plan of the house: floors, no arrow up a floor, no import circle.

Floors, lowest first: ``core`` (science) < ``dataio`` (bytes and files) < ``modelgap``
(the model-gap workflow) < ``session`` (collect, fit and accept, save: what every front
door shares) < ``sim`` (simulated hardware) < ``nodes`` and ``cli`` (the two front doors,
which do not import each other). A module may import from its own
floor and the floors below; every import counts, also one inside a function.
"""

import ast
import os

import pytest

PACKAGE = 'accel_calib_ros'
ROOT = os.path.join(os.path.dirname(__file__), '..', '..', PACKAGE)
FLOORS = {'core': 0, 'dataio': 1, 'modelgap': 2, 'session': 3, 'sim': 4, 'nodes': 5, 'cli': 5}


def modules():
    """Return {dotted module name: path} of the package."""
    out = {}
    for folder, _, files in os.walk(ROOT):
        for name in files:
            if name.endswith('.py'):
                path = os.path.join(folder, name)
                rel = os.path.relpath(path, os.path.join(ROOT, '..'))[:-3].split(os.sep)
                if rel[-1] == '__init__':
                    rel = rel[:-1]
                out['.'.join(rel)] = path
    return out


def imports(name, path, known):
    """Return the package modules that the module called ``name`` imports, anywhere in it."""
    with open(path, encoding='utf-8') as f:
        tree = ast.parse(f.read())
    package = name if path.endswith('__init__.py') else name.rsplit('.', 1)[0]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split('.')
                base = base[:len(base) - node.level + 1]
                target = '.'.join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ''
            for alias in node.names:            # 'from pkg import module' names a module
                full = f'{target}.{alias.name}'
                found.add(full if full in known else target)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
    return {m for m in found if m in known and m != name}


def graph():
    known = modules()
    return {name: imports(name, path, known) for name, path in known.items()}


def floor(module):
    parts = module.split('.')
    return FLOORS.get(parts[1]) if len(parts) > 1 else None


def test_every_module_lives_on_a_floor():
    loose = [m for m in modules() if m != PACKAGE and floor(m) is None]
    assert loose == [], f'modules outside the floors {sorted(FLOORS)}: {loose}'


def test_no_arrow_runs_up_a_floor():
    up = sorted(f'{a} -> {b}' for a, targets in graph().items() for b in targets
                if floor(a) is not None and floor(b) is not None and floor(b) > floor(a))
    assert up == []


def test_the_two_front_doors_do_not_import_each_other():
    across = sorted(f'{a} -> {b}' for a, targets in graph().items() for b in targets
                    if {a.split('.')[1:2][0], b.split('.')[1:2][0]} == {'nodes', 'cli'})
    assert across == []


def test_no_import_circle():
    g = graph()
    state, cycles = {}, []

    def visit(node, stack):
        state[node] = 1
        stack.append(node)
        for nxt in sorted(g[node]):
            if state.get(nxt) == 1:
                cycles.append(stack[stack.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt, stack)
        stack.pop()
        state[node] = 2

    for node in sorted(g):
        if node not in state:
            visit(node, [])
    # A package __init__ that re-exports its children is not a circle of the plan.
    cycles = [c for c in cycles if not all(a.startswith(b + '.') or b.startswith(a + '.')
                                           for a, b in zip(c, c[1:]))]
    assert cycles == [], ' | '.join(' -> '.join(c) for c in cycles)


MAX_LINES = 600


def test_no_module_is_longer_than_a_reader_can_hold():
    """Every module at most 600 lines: a longer one is split by idea, not by length."""
    long = {}
    for name, path in modules().items():
        with open(path, encoding='utf-8') as f:
            count = sum(1 for _ in f)
        if count > MAX_LINES:
            long[name] = count
    assert long == {}


def test_no_two_modules_share_a_name_across_floors():
    """A name means one idea: ``sim.session`` beside the ``session`` floor would not."""
    by_name = {}
    for name in modules():
        parts = name.split('.')
        if len(parts) > 2:
            by_name.setdefault(parts[-1], set()).add(parts[1])
    # The same idea on two floors, kept on purpose: a command named after its subject
    # (allan, fit, health, history), a node after what it serves (calibration, correction:
    # the core holds the result and the filter, the node the shell), each front door's
    # shared helpers (common), the static windows (the core detects them, the session
    # floor collects them as typed records for every front door).
    same_idea = {'allan', 'fit', 'health', 'history', 'calibration', 'correction', 'common',
                 'windows'}
    shared = {n: sorted(f) for n, f in by_name.items() if len(f) > 1 and n not in same_idea}
    assert shared == {}


@pytest.mark.parametrize('command', ['fit', 'apply', 'history', 'allan'])
def test_a_command_imports_no_other_command(command):
    name = f'{PACKAGE}.cli.{command}'
    others = {f'{PACKAGE}.cli.{c}' for c in ('fit', 'apply', 'simulate', 'diagnose', 'allan',
                                             'advise', 'guide', 'history', 'simulate_device')}
    assert graph()[name] & (others - {name}) == set()
