"""
A plain record class for the session floor's data: named fields with defaults.

A ``dataclass`` writes and compiles its methods when the class is defined, about half a
millisecond each; the session floor is imported by every ``accel-calib fit`` and the
node, whose start-up is counted (bench/bench_startup.py). :class:`Record` gives the same
use (keyword or positional construction, defaults, a fresh list per instance,
``replace``, a readable ``repr``) for the cost of an ordinary class.
"""

FRESH = (list, dict)
"""Defaults given as one of these types are called: a fresh, unshared value each time."""


class Record:
    """
    Fields and defaults in ``FIELDS`` (ordered: positional arguments follow that order).

    A subclass may define ``_check(self)``, called after the fields are set (the place of a
    dataclass's ``__post_init__``).
    """

    FIELDS = {}

    def __init__(self, *args, **kwargs):
        names = list(self.FIELDS)
        if len(args) > len(names):
            raise TypeError(f'{type(self).__name__} takes at most {len(names)} arguments')
        values = dict(zip(names, args))
        for name in kwargs:
            if name not in self.FIELDS or name in values:
                raise TypeError(f'{type(self).__name__}: unexpected or repeated argument '
                                f'{name!r}')
        values.update(kwargs)
        for name, default in self.FIELDS.items():
            if name in values:
                value = values[name]
            else:
                value = default() if default in FRESH else default
            setattr(self, name, value)
        self._check()

    def _check(self):
        """Check or convert the fields (nothing by default)."""

    def replace(self, **changes):
        """Return a copy with ``changes`` (as ``dataclasses.replace``)."""
        return type(self)(**{**{name: getattr(self, name) for name in self.FIELDS},
                             **changes})

    def __repr__(self):
        inner = ', '.join(f'{name}={getattr(self, name)!r}' for name in self.FIELDS)
        return f'{type(self).__name__}({inner})'
