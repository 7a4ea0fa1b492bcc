"""Load elements: explicit forces on the bodies of a scene."""

from __future__ import annotations


class LoadElement:
    """What :class:`Scene` accepts as an explicit load: an object with

        master_loads(t) -> iterable of (body, array)

    per body of the scene: an FEM body (nodal forces in its blocked dof layout,
    the length of ``body.v.x.array``), a rigid body (the wrench [f; tau about the
    COM], world) or a reduced body (its generalized force, r). Loads enter the
    step explicitly (b += h f) and the static residual; e.g. a pressure on a skin
    mapped to its masters by G^T (virtual work).
    """

    @staticmethod
    def is_load(item) -> bool:
        return callable(getattr(item, "master_loads", None))
