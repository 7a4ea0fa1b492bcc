"""Load elements: explicit forces on the bodies of a scene."""

from __future__ import annotations


class LoadElement:
    """What :class:`Scene` accepts as an explicit load: an object with

        master_loads(t) -> iterable of (body, array)
        bodies -> tuple of the bodies it may load

    per body of the scene: an FEM body (nodal forces in its blocked dof layout,
    the length of ``body.v.x.array``), a rigid body (the wrench [f; tau about the
    COM], world) or a reduced body (its generalized force, r). Loads enter the
    step explicitly (b += h f) and the static residual; e.g. a pressure on a skin
    mapped to its masters by G^T (virtual work). ``bodies`` couples them: a
    deformable body that no attachment, path or load names is stepped on its own
    (its own solver, in parallel under MPI), so a load must name every body it
    loads.

    Optional: ``potential_energy(t) -> float``, the potential of a conservative load
    (-f . x for a constant force f at a point x), whose gradient is minus
    ``master_loads(t)``; statics then takes the scene's energy as its merit
    (:meth:`~artifem.scene.Scene.solve_static`), else the force residual.
    """

    @staticmethod
    def is_load(item) -> bool:
        return callable(getattr(item, "master_loads", None))
