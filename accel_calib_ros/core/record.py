"""
Plain record classes: named fields with defaults, for the cost of an ordinary class.

A ``dataclass`` writes and compiles its methods when the class is defined, about half a
millisecond each; a dozen result classes lie on the path of every ``accel-calib fit``
and node start, whose start-up is counted (bench/bench_startup.py). A record gives the
same use (construction by position or keyword, defaults, a fresh value per instance,
``replace``, ``==`` field by field, a readable ``repr``) with methods shared by all.

Two spellings of the same thing:

* :func:`record`, a class decorator reading a dataclass-style body: annotated fields,
  defaults, :class:`fresh` for ``field(default_factory=...)``, ``__post_init__``;
* :class:`Record`, a base class whose ``FIELDS`` dict names the fields and defaults
  (``list`` or ``dict`` as a default means a fresh one), with ``_check`` as the hook.
"""

FRESH = (list, dict)
"""Defaults given as one of these types are called: a fresh, unshared value each time."""

_REQUIRED = object()
"""The default of a field that has none (an argument is required)."""


class fresh:
    """A default made anew for every instance: ``fresh(list)``, ``fresh(lambda: ...)``."""

    __slots__ = ('factory',)

    def __init__(self, factory):
        self.factory = factory


class Record:
    """
    Fields and defaults in ``FIELDS`` (ordered: positional arguments follow that order).

    A subclass may define ``_check(self)`` (or ``__post_init__``), called after the fields
    are set.
    """

    FIELDS = {}

    def __init__(self, *args, **kwargs):
        fields = self.FIELDS
        if len(args) > len(fields):
            raise TypeError(f'{type(self).__name__} takes at most {len(fields)} arguments')
        values = dict(zip(fields, args))
        for name in kwargs:
            if name not in fields or name in values:
                raise TypeError(f'{type(self).__name__}: unexpected or repeated argument '
                                f'{name!r}')
        values.update(kwargs)
        for name, default in fields.items():
            if name in values:
                value = values[name]
            elif default is _REQUIRED:
                raise TypeError(f'{type(self).__name__}: missing argument {name!r}')
            elif isinstance(default, fresh):
                value = default.factory()
            else:
                value = default() if default in FRESH else default
            setattr(self, name, value)
        self._check()

    def _check(self):
        """Check or convert the fields (``__post_init__`` when the class has one)."""
        post = getattr(self, '__post_init__', None)
        if post is not None:
            post()

    def replace(self, **changes):
        """Return a copy with ``changes`` (as ``dataclasses.replace``)."""
        return type(self)(**{**{name: getattr(self, name) for name in self.FIELDS},
                             **changes})

    def __eq__(self, other):
        """Equal when of the same class with equal fields (as a dataclass)."""
        if other.__class__ is not self.__class__:
            return NotImplemented
        return all(getattr(self, n) is getattr(other, n) or getattr(self, n) == getattr(other, n)
                   for n in self.FIELDS)

    __hash__ = None

    def __repr__(self):
        inner = ', '.join(f'{name}={getattr(self, name)!r}' for name in self.FIELDS)
        return f'{type(self).__name__}({inner})'


def record(cls):
    """
    Make ``cls`` a record from its dataclass-style body (the decorator's use of ``dataclass``).

    Its annotated names are the fields, in order, after any of a record base class; their
    class values the defaults (:class:`fresh` for one made per instance). The methods of
    :class:`Record` are added where the class does not define its own.
    """
    fields = dict(getattr(cls, 'FIELDS', {}))
    for name in cls.__dict__.get('__annotations__', {}):
        default = cls.__dict__.get(name, _REQUIRED)
        fields[name] = default
        if isinstance(default, fresh):
            delattr(cls, name)
    cls.FIELDS = fields
    for name in ('__init__', '_check', 'replace', '__eq__', '__hash__', '__repr__'):
        if name not in cls.__dict__:
            setattr(cls, name, Record.__dict__[name])
    return cls
