"""artifem's exceptions: one base class, two families.

``ArtifemError`` is the base of everything artifem raises on purpose, so a
script or the command line can tell a model's complaint from a bug:

- ``InputError`` (also a ``ValueError``): bad input, raised before any long work
  starts; the message says what and where (file and line, body, element,
  muscle, joint). ``UnknownNameError`` (also a ``KeyError``) names an unknown
  muscle, motion, joint...; ``MeshError`` a mesh that cannot be used.
- ``SolverError`` (also a ``RuntimeError``): a step or solve that failed; the
  message says why in terms of the model (which body, element, joint, time).

The two roots live in the lowest layer, ``artifem.forms.errors`` (the materials raise
InputError too); this module imports nothing else of artifem: every layer may raise these.
"""

from __future__ import annotations

import numpy as np

from artifem.forms.errors import ArtifemError, InputError


class UnknownNameError(InputError, KeyError):
    """A name (muscle, motion, joint, case...) that the model does not have."""

    __str__ = Exception.__str__  # KeyError would quote the message


class InputFileNotFoundError(InputError, FileNotFoundError):
    """An input file that does not exist."""


class MeshError(InputError):
    """A mesh file or mesh that cannot be used; the message says what and where."""


class MeshFileNotFoundError(MeshError, FileNotFoundError):
    """A mesh file that does not exist."""


class OutsideMeshError(InputError):
    """Embedded points lie outside the body (and ``snap`` was not requested)."""

    def __init__(self, name: str, outside: np.ndarray, distance: np.ndarray):
        self.outside, self.distance = outside, distance
        worst = int(outside[np.argmax(distance[outside])])
        super().__init__(
            f"{outside.size} embedded point(s) lie outside FEM body {name!r}; the worst is "
            f"point {worst} at distance {distance[worst]:.4g}; pass snap=True to move them to "
            f"the closest point of the nearest element"
        )


class SolverError(ArtifemError, RuntimeError):
    """A step or a solve failed; the message says why in terms of the model."""


class StepFailed(SolverError):
    """A step could not be completed at this step size (``iterations``: the Newton
    iterations spent on it, where a solve counts them)."""

    def __init__(self, message: str = "", iterations: int = 0):
        super().__init__(message)
        self.iterations = int(iterations)


class SingularSystem(StepFailed):
    """A linear system with a zero pivot. ``matrix``: the system itself where it was
    small enough to factor densely (else None), so that whoever knows what its unknowns
    are can say which motions nothing resists (:meth:`null_space`)."""

    def __init__(self, message: str = "", matrix: np.ndarray | None = None, iterations: int = 0):
        super().__init__(message, iterations)
        self.matrix = matrix

    def null_space(self, rtol: float = 1e-10) -> np.ndarray | None:
        """Orthonormal columns spanning the near null space of ``matrix``: its right
        singular vectors with sigma <= rtol sigma_max (at least the smallest one); None
        without the matrix."""
        if self.matrix is None or not np.all(np.isfinite(self.matrix)):
            return None
        _, sigma, vt = np.linalg.svd(self.matrix)
        keep = max(int(np.count_nonzero(sigma <= rtol * max(sigma[0], 1e-300))), 1)
        return vt[-keep:].T


class LinearSolveError(SolverError):
    """The KSP did not converge (or the factorization failed) for this matrix."""


class ElementInversionError(SolverError):
    """det F <= 0 at a quadrature point, and the step could not recover: names the body,
    the time, the elements (input indices) and the smallest det F."""

    def __init__(
        self, time: float, elements: np.ndarray, min_det: float, detail: str = "", body: str = ""
    ):
        self.time, self.elements, self.min_det = time, np.asarray(elements), min_det
        self.body = body
        shown = ", ".join(str(e) for e in self.elements[:20])
        more = f" (and {len(self.elements) - 20} more)" if len(self.elements) > 20 else ""
        where = f" of body {body!r}" if body else ""
        super().__init__(
            f"element inversion at t = {time:.6g} s: det F = {min_det:.4g} <= 0 in "
            f"{len(self.elements)} element(s){where} [{shown}{more}] (input element indices)"
            + (f"; {detail}" if detail else "")
        )
