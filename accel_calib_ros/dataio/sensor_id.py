"""
Sensor ids: the one rule for the name a sensor goes by (history, calibration file, nodes).

A sensor id is an id from the firmware, a port or a name the user gives. It is
normalised, then checked, the same way at every border (``--sensor`` of the CLI, the
``sensor_id`` parameter of the calibration node, the history database):

- surrounding white space is dropped and the text is put in Unicode NFC form, so
  ``' padded '`` and ``'padded'`` (or a composed and a decomposed ``é``) are one sensor;
- what is left must be printable: control characters, bidi overrides, zero-width and
  other invisible characters are refused (they would make two ids that look the same,
  or rewrite a terminal line when listed);
- at most ``MAX_SENSOR_ID`` characters, and not empty.

Standard library only.
"""

import unicodedata

from ..core.errors import InputError

MAX_SENSOR_ID = 200
"""Longest sensor id accepted, characters."""
DEFAULT_SENSOR = 'imu_link'
"""The sensor the nodes serve by default (frame_id ``imu_link`` at the root namespace)."""


def normalise_sensor_id(text):
    """
    Return the normal form of a sensor id, or refuse it.

    :param text: the id as given.
    :return: the id stripped and in NFC form.
    :raises InputError: not text, empty, too long, or holding an invisible or control
        character (the message shows the id escaped).
    """
    if not isinstance(text, str):
        raise InputError(f'a sensor id must be text, got {type(text).__name__}')
    value = unicodedata.normalize('NFC', text).strip()
    if not value:
        raise InputError('a sensor id must not be empty (or only spaces)')
    if len(value) > MAX_SENSOR_ID:
        raise InputError(f'a sensor id is at most {MAX_SENSOR_ID} characters, got '
                         f'{len(value)}')
    bad = [c for c in value if not c.isprintable()]
    if bad:
        shown = ascii(value[:60])
        raise InputError(f'a sensor id must be printable text: {shown} holds '
                         f'U+{ord(bad[0]):04X} ({unicodedata.name(bad[0], "a control")})'
                         ' (control, bidi or invisible characters are refused)')
    return value
