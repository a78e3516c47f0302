"""
Reading YAML as the calibration files need it, and the validators of their schema.

Duplicate keys are refused and nesting is bounded; each validator raises :class:`Bad` with
a one-line reason.
"""

import math
import re

import numpy as np
import yaml


class _UniqueKeys:
    """Mixin of a YAML loader: a mapping with the same key twice is refused (no last-win)."""

    def construct_mapping(self, node, deep=False):
        """Build a mapping; a repeated key is a ConstructorError naming it and its line."""
        if isinstance(node, yaml.MappingNode):
            self.flatten_mapping(node)
            seen = {}
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=True)
                try:
                    hash(key)
                except TypeError:
                    continue                     # the base class words this one
                if key in seen:
                    shown = repr(key) if len(repr(key)) <= 40 else repr(key)[:39] + '…'
                    raise yaml.constructor.ConstructorError(
                        None, None, f'duplicate key {shown} (line {seen[key] + 1} and line '
                        f'{key_node.start_mark.line + 1}): say it once', key_node.start_mark)
                seen[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep)


class UniqueKeyLoader(_UniqueKeys, yaml.SafeLoader):
    """A YAML SafeLoader that refuses a mapping with the same key twice."""


# libyaml's parser (PyYAML's C extension, in the PyPI wheels and Debian's python3-yaml)
# reads a file 10-20 times faster: a reload never stalls a node for long.
_Loader = type('_FastUniqueKeyLoader', (_UniqueKeys, yaml.CSafeLoader), {}) \
    if getattr(yaml, '__with_libyaml__', False) else UniqueKeyLoader

_QUOTED_OR_COMMENT = re.compile(r"'(?:[^']|'')*'|\"(?:[^\"\\]|\\.)*\"|(?:(?<=\s)|^)#[^\n]*",
                                re.M)


def nesting_depth(text):
    """
    Return an upper bound of how deep the collections of YAML ``text`` nest, unparsed.

    Flow brackets (``[``, ``{``) outside quotes and comments, plus a line's indentation
    (one level per column at most) and its leading ``- `` items; linear in the text.
    """
    plain = _QUOTED_OR_COMMENT.sub('', text)
    steps = np.frombuffer(re.sub(r'[^\[\]{}]', '', plain).encode('ascii'), np.uint8)
    flow = int(np.cumsum(np.where((steps == 91) | (steps == 123), 1, -1)).max()) \
        if len(steps) else 0
    block = max((len(m.group(1)) + m.group(2).count('-')
                 for m in re.finditer(r'^( *)((?:- +)*)', plain, re.M)), default=0)
    return flow + block


def load_yaml(text):
    """Parse YAML text safely, refusing duplicate keys (yaml.YAMLError on any problem)."""
    return yaml.load(text, Loader=_Loader)     # noqa: S506 - a SafeLoader subclass


class Bad(Exception):
    """Internal: a validation failure with a one-line reason."""


def _number(value, name, low=-math.inf, high=math.inf, integer=False):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise Bad(f'{name} must be a number, got {type(value).__name__}')
    if integer and not (isinstance(value, int) or float(value).is_integer()):
        raise Bad(f'{name} must be an integer, got {value!r}')
    try:
        x = float(value)
    except OverflowError:
        raise Bad(f'{name} is out of range') from None
    if not math.isfinite(x):
        raise Bad(f'{name} must be finite, got {value!r}')
    if not low <= x <= high:
        raise Bad(f'{name} = {x:g} is outside [{low:g}, {high:g}]')
    return int(x) if integer else x


def _vector(value, name, size, low=-math.inf, high=math.inf):
    if not isinstance(value, (list, tuple)) or len(value) != size:
        raise Bad(f'{name} must be a list of {size} numbers')
    return np.array([_number(v, f'{name}[{k}]', low, high) for k, v in enumerate(value)])


def _matrix(value, name, rows, cols):
    if not isinstance(value, (list, tuple)) or len(value) != rows:
        raise Bad(f'{name} must be a {rows}x{cols} list of lists of numbers')
    return np.vstack([_vector(r, f'{name}[{k}]', cols) for k, r in enumerate(value)])


def _mapping(value, name):
    if not isinstance(value, dict):
        raise Bad(f'{name} must be a mapping, got {type(value).__name__}')
    return value


def _string(value, name, max_len=1000):
    if value is None:
        return ''
    if isinstance(value, bool) or not isinstance(value, (str, int, float)):
        raise Bad(f'{name} must be text')
    text = str(value)
    if len(text) > max_len:
        raise Bad(f'{name} is longer than {max_len} characters')
    return text


def _found(value):
    """Say what a value is, for a message: type and (short) value."""
    kinds = {bool: 'the boolean', str: 'the string', int: 'the integer', float: 'the number',
             type(None): 'nothing (the key is missing or empty)'}
    kind = kinds.get(type(value), f'a {type(value).__name__}')
    if value is None:
        return kind
    text = repr(value)
    return f'{kind} {text if len(text) <= 30 else text[:29] + "…"}'


def _optional(d, key, parse):
    value = d.get(key)
    return None if value is None else parse(value)
