"""Exceptions raised by geofix.

Every error a user can cause (a bad map, a bad scenario, a track that leaves the map)
is a :class:`GeofixError`; the command line prints its message on one line and exits
non-zero, never a traceback.
"""


class GeofixError(Exception):
    """Base class of every error geofix raises on purpose."""


class MapError(GeofixError):
    """A map file is missing, unreadable, or has no usable data."""


class ConfigError(GeofixError):
    """A scenario or method specification is invalid."""


class TrackOffMapError(GeofixError):
    """A track (true, indicated or candidate) leaves the map or its valid data."""


class MatchError(GeofixError):
    """A matcher could not produce a fix (for example an all-NaN search window)."""


class MemoryBudgetError(GeofixError):
    """An input would need more memory than the budget allows (see :mod:`geofix.memory`)."""


class GeofixWarning(UserWarning):
    """Something was adjusted rather than refused (e.g. ``--jobs`` capped at the cores)."""


class InputError(GeofixError):
    """An online input (a navigation record, a ping) the navigator refuses.

    It is malformed, out of order or out of bounds; the navigator keeps its state.
    """


class OutputError(GeofixError):
    """An output file could not be written (disk full, permission denied, not a file).

    The message names the path; no partial file is left under that name.
    """
