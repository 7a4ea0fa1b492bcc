"""artifem: combined FEM-multibody anatomical simulation on FEniCSx.

Implements the techniques of Lloyd et al. 2019, "New Techniques for Combined
FEM-Multibody Anatomical Simulation": full and reduced FEM bodies, rigid
bodies, attachments through G = df/dx_m with forces mapped back by G^T, and
embedded / skin meshes.

The public API without deep imports::

    import artifem as af
    scene = af.Scene(gravity=(0, 0, -9.81))
    scene.add(af.FemBody(...), af.RigidBody(...), ...)
    run = af.simulate(scene, 1.0, 0.01, record={...}, vtx="out/")

Its names are loaded on first use (PEP 562), so ``import artifem`` stays cheap
and every module may import the package first (the MPI ordering below) without
loading the layers above it.
"""

import importlib

# The dolfinx-solver wheel must order mpi4py ahead of its compiled modules:
# this import has to run before dolfinx, petsc4py or slepc4py are imported.
import dolfinx_solver  # noqa: F401

__version__ = "0.1.0"

#: public name -> the module that defines it
_PUBLIC = {
    **dict.fromkeys(["Scene", "SceneState"], "artifem.scene.scene"),
    **dict.fromkeys(["simulate", "Run"], "artifem.scene.run"),
    "FemBody": "artifem.fem_body",
    "Incompressible": "artifem.incompressibility",
    "SurfaceLoad": "artifem.surface_loads",
    "ReducedFemBody": "artifem.reduction.reduced_body",
    **dict.fromkeys(["RigidBody", "Frame"], "artifem.multibody.rigid_body"),
    **dict.fromkeys(
        [
            "FixedJoint",
            "SphericalJoint",
            "RevoluteJoint",
            "SliderJoint",
            "PlanarJoint",
            "axis_rotation",
        ],
        "artifem.multibody.joints",
    ),
    **dict.fromkeys(["PlaneContact", "ContactForces"], "artifem.multibody.contact"),
    **dict.fromkeys(["MeshContact", "MeshContactForces"], "artifem.multibody.mesh_contact"),
    "ElasticFoundation": "artifem.multibody.foundation",
    **dict.fromkeys(["contact_pressure", "ContactPressure"], "artifem.multibody.contact_pressure"),
    **dict.fromkeys(
        [
            "NodeAttachment",
            "RigidAttachment",
            "FrameAttachment",
            "EmbeddedFemAttachment",
            "LiftAttachment",
            "FemPoint",
        ],
        "artifem.multibody.attachments",
    ),
    "FemFrame": "artifem.multibody.frame_attachments",
    **dict.fromkeys(
        ["shape_function_weights", "support_weights", "nearest_nodes"],
        "artifem.multibody.point_attachments",
    ),
    "PointPath": "artifem.multibody.point_paths",
    "FramePath": "artifem.multibody.frame_paths",
    **dict.fromkeys(
        ["AxialSpring", "ThelenMuscle", "ThelenParameters"], "artifem.multibody.muscles"
    ),
    **dict.fromkeys(["SkinMesh", "SkinPressure"], "artifem.multibody.skin"),
    "ExcitationSchedule": "artifem.excitation",
    **dict.fromkeys(
        [
            "MooneyRivlin",
            "NeoHookean",
            "LinearElastic",
            "StVenantKirchhoff",
            "BlemkerFiber",
            "CombinedMaterial",
        ],
        "artifem.forms",
    ),
    "read_mesh": "artifem.io.readers",
    "to_dolfinx": "artifem.io.to_dolfinx",
    "MeshData": "artifem.io.mesh_data",
    "check_orientation": "artifem.io.mesh_checks",
    "spherical_shell_octant": "artifem.io.shell_mesh",
    **dict.fromkeys(
        ["point_response", "stress_stretch_curves", "plot_stress_stretch"],
        "artifem.material_response",
    ),
    "render_bodies": "artifem.render",
    **dict.fromkeys(
        [
            "ArtifemError",
            "InputError",
            "UnknownNameError",
            "MeshError",
            "OutsideMeshError",
            "SolverError",
            "StepFailed",
            "SingularSystem",
            "ElementInversionError",
        ],
        "artifem.errors",
    ),
}


def lazy_exports(package: str, namespace: dict, public: dict[str, str]):
    """``__all__``, ``__getattr__`` and ``__dir__`` of a package whose public names
    (name -> defining module) are imported on first use (PEP 562), so that importing the
    package, or any module inside it, loads nothing of the layers above."""

    def getattr_(name: str):
        module = public.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        namespace[name] = value
        return value

    def dir_():
        return sorted(set(namespace) | set(public))

    return sorted(public), getattr_, dir_


__all__, __getattr__, __dir__ = lazy_exports(__name__, globals(), _PUBLIC)
