"""artifem: combined FEM-multibody anatomical simulation on FEniCSx.

Implements the techniques of Lloyd et al. 2019, "New Techniques for Combined
FEM-Multibody Anatomical Simulation": full and reduced FEM bodies, rigid
bodies, attachments through G = df/dx_m with forces mapped back by G^T, and
embedded / skin meshes.
"""

# The dolfinx-solver wheel must order mpi4py ahead of its compiled modules:
# this import has to run before dolfinx, petsc4py or slepc4py are imported.
import dolfinx_solver  # noqa: F401

__version__ = "0.1.0"
