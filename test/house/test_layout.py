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


def parse(path):
    """Return the syntax tree of the Python file at ``path``."""
    with open(path, encoding='utf-8') as f:
        return ast.parse(f.read())


def imports(name, path, known):
    """Return the package modules that the module called ``name`` imports, anywhere in it."""
    tree = parse(path)
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


# -- one name, one home ----------------------------------------------------------------------

MAX_SHARED_CONSTANTS = 4
"""Constant names defined in more than one module, at most (each node's parameter table is
``PARAMS``, each node's queue ``QUEUE_DEPTH``: the same idea, one per node)."""


def constants():
    """Return {constant name: [modules defining it]} (module-level UPPER_CASE assignments)."""
    import re
    defined = {}
    for name, path in modules().items():
        tree = parse(path)
        for node in tree.body:
            targets = node.targets if isinstance(node, ast.Assign) else \
                [node.target] if isinstance(node, ast.AnnAssign) and node.value else []
            for target in targets:
                if isinstance(target, ast.Name) and re.fullmatch(r'[A-Z][A-Z0-9_]*', target.id):
                    defined.setdefault(target.id, []).append(name)
    return defined


def test_a_constant_is_defined_once_or_two_ideas_have_two_names():
    """A value defined in two modules drifts; one home, imported where it is used."""
    shared = {n: m for n, m in constants().items() if len(m) > 1}
    assert len(shared) <= MAX_SHARED_CONSTANTS, shared


def _rclpy_private_names():
    """Return the private names of rclpy's classes (``self._x`` it sets, ``def _x``)."""
    import importlib.util
    spec = importlib.util.find_spec('rclpy')
    if spec is None or not spec.origin:
        pytest.skip('rclpy is not installed')
    private = set()
    for folder, _, files in os.walk(os.path.dirname(spec.origin)):
        for file in files:
            if not file.endswith('.py'):
                continue
            tree = parse(os.path.join(folder, file))
            for node in ast.walk(tree):
                if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and \
                        node.value.id == 'self' and _private(node.attr):
                    private.add(node.attr)
                elif isinstance(node, ast.ClassDef):
                    private.update(b.name for b in node.body if isinstance(
                        b, (ast.FunctionDef, ast.AsyncFunctionDef)) and _private(b.name))
    return private


def _private(name):
    return name.startswith('_') and not name.startswith('__')


def _our_names():
    """Return the names the package itself gives its objects (``self._x = ...``, ``def _x``)."""
    ours = set()
    for path in modules().values():
        tree = parse(path)
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                ours.add(node.name)
            elif isinstance(node, (ast.Assign, ast.AugAssign, ast.AnnAssign)):
                for target in node.targets if isinstance(node, ast.Assign) else [node.target]:
                    ours.update(e.attr for e in ast.walk(target)
                                if isinstance(e, ast.Attribute) and isinstance(e.value, ast.Name)
                                and e.value.id == 'self')
    return ours


def test_the_nodes_use_no_private_attribute_of_rclpy():
    """No ``_nodes``, ``_guard``, ``_parameter_overrides``: rclpy changes its privates freely."""
    theirs = _rclpy_private_names() - _our_names()
    found = []
    for name, path in modules().items():
        if floor(name) != FLOORS['nodes'] or not name.startswith(f'{PACKAGE}.nodes'):
            continue
        tree = parse(path)
        for node in ast.walk(tree):
            used = None
            if isinstance(node, ast.Attribute):
                used = node.attr
            elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and \
                    node.func.id in ('getattr', 'setattr', 'hasattr', 'delattr') and \
                    len(node.args) > 1 and isinstance(node.args[1], ast.Constant):
                used = node.args[1].value
            elif isinstance(node, ast.ImportFrom) and (node.module or '').startswith('rclpy'):
                hidden = [a.name for a in node.names if _private(a.name)]
                if hidden or any(_private(part) for part in node.module.split('.')):
                    found.append(f'{name}:{node.lineno} from {node.module} import {hidden}')
            if isinstance(used, str) and used in theirs:
                found.append(f'{name}:{node.lineno} {used}')
    assert found == []


def test_the_guide_reads_the_port_through_the_link():
    """One serial stack: the guide's port is read by ``dataio.link``, as the driver's."""
    path = modules()[f'{PACKAGE}.cli.guide_sources']
    known = modules()
    used = imports(f'{PACKAGE}.cli.guide_sources', path, known)
    assert f'{PACKAGE}.dataio.link' in used or f'{PACKAGE}.dataio.link.serial_link' in used
    tree = parse(path)
    direct = [n.lineno for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))
              and any(a.name == 'serial' or a.name.startswith('serial.') for a in n.names)
              or isinstance(n, ast.ImportFrom) and (n.module or '').split('.')[0] == 'serial']
    assert direct == [], 'the guide opens pyserial itself'


# -- a front page, a map, no history in the code ---------------------------------------------

REPO = os.path.join(ROOT, '..')
MAX_README_LINES = 250


def test_the_readme_is_a_front_page_that_links_the_map():
    """README.md: what it is, the two commands, on a robot, where to read next."""
    with open(os.path.join(REPO, 'README.md'), encoding='utf-8') as f:
        text = f.read()
    assert text.count('\n') <= MAX_README_LINES
    assert '](docs/architecture.md)' in text
    assert 'make demo' in text and 'make test' in text
    assert os.path.isfile(os.path.join(REPO, 'docs', 'architecture.md'))


def test_no_issue_numbers_in_the_package_docs_or_test_names():
    """History belongs to the tracker and the log, not to the code, the docs or a test's name."""
    import re
    pattern = re.compile(r'\bissues?\s*#?\s*\d+', re.IGNORECASE)
    found = []
    places = [os.path.join(REPO, p) for p in ('accel_calib_ros', 'docs', 'launch', 'config')]
    files = [os.path.join(REPO, 'README.md')]
    for place in places:
        for folder, _, names in os.walk(place):
            files += [os.path.join(folder, n) for n in names
                      if n.endswith(('.py', '.md', '.yaml', '.txt'))]
    for path in files:
        with open(path, encoding='utf-8') as f:
            for number, line in enumerate(f, 1):
                if pattern.search(line):
                    found.append(f'{os.path.relpath(path, REPO)}:{number}')
    tests = os.path.join(REPO, 'test')
    for folder, _, names in os.walk(tests):
        for name in names:
            if name.endswith('.py'):
                with open(os.path.join(folder, name), encoding='utf-8') as f:
                    found += [f'{name}: {n}' for n in re.findall(r'def (test\w*)', f.read())
                              if re.search(r'issue_?\d', n)]
            if re.search(r'issue_?\d', name):
                found.append(name)
    assert found == []
