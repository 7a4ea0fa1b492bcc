"""The root of artifem's exceptions, here because this is the lowest layer that raises one.

``ArtifemError`` is the base of everything artifem raises on purpose and ``InputError``
(also a ``ValueError``) its bad-input family; ``artifem.errors`` re-exports both beside
the rest of the hierarchy, so ``except af.ArtifemError`` catches a bad material
parameter as it catches any other complaint of a model.
"""


class ArtifemError(Exception):
    """Base class of every error artifem raises on purpose."""


class InputError(ArtifemError, ValueError):
    """Bad input (a value, a file, a name); the message says what and where."""
