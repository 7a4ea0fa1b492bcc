"""Contact pressure of an FEM body's nodes from the normal forces of its contact rows.

Each contact node i carries the normal force f_n,i (N, the contact's ``normal_forces``:
a plane's point force, a mesh pair's shared by its coefficients). Its pressure is that
force over the
node's tributary area on the body's boundary, the lumped boundary "mass":

    p_i = f_n,i / A_i,        A_i = int_{dOmega} N_i dA,

N_i the node's P1 shape function, the integral over the exterior facets (reference
configuration dA, or the current one da = J |F^-T N| dA). The A_i sum to the boundary's
area. Within the contact zone p_i is the nodal value of the pressure field whose lumped
integral gives the forces; at the edge of the zone a node's area reaches beyond it, so
its p_i is smaller than the field there (the edge is resolved to a node spacing).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import ufl
from dolfinx import fem, la

from artifem.errors import InputError
from artifem.fem_body import FemBody

__all__ = ["ContactPressure", "boundary_areas", "contact_pressure"]


class ContactPressure(NamedTuple):
    """points: the input node indices of the contact's nodes (zero pressure where they had
    no force); pressure: (k,) f_n / A (Pa); area: (k,) their tributary areas A (m^2);
    nodal: the pressure at every local node, indexed like a scalar P1 function's dofs on the
    body's mesh (zero off the contact; ``fem.Function(...).x.array[:] = nodal``)."""

    points: np.ndarray
    pressure: np.ndarray
    area: np.ndarray
    nodal: np.ndarray


def boundary_areas(
    body: FemBody, *, quadrature_degree: int = 2, configuration: str = "reference"
) -> np.ndarray:
    """A_i = int over the exterior facets of N_i dA, at every local node (owned and ghost),
    indexed by the body's block dofs (equal to a scalar P1 space's dofs on its mesh).

    ``configuration``: "reference" (dA) or "current" (da = J |F^-T N| dA with the body's
    displacement u). ``quadrature_degree``: of the facet integral (2 integrates the
    reference one exactly; the current one's J |F^-T N| is piecewise constant on P1)."""
    if configuration not in ("reference", "current"):
        raise InputError(
            f"boundary_areas: configuration must be 'reference' or 'current', got {configuration!r}"
        )
    domain = body.mesh
    S = fem.functionspace(domain, ("Lagrange", 1))
    if not np.array_equal(S.dofmap.list, body.V.dofmap.list):
        raise InputError(
            f"FemBody {body.name!r}: its scalar P1 dofs differ from its block "
            "dofs; the nodal areas cannot be indexed by node"
        )
    v = ufl.TestFunction(S)
    ds = ufl.Measure("ds", domain=domain, metadata={"quadrature_degree": quadrature_degree})
    if configuration == "reference":
        density = 1.0
    else:
        F = ufl.Identity(3) + ufl.grad(body.u)
        N = ufl.FacetNormal(domain)
        FN = ufl.inv(F).T * N
        density = ufl.det(F) * ufl.sqrt(ufl.dot(FN, FN))
    b = fem.assemble_vector(fem.form(density * v * ds))
    b.scatter_reverse(la.InsertMode.add)
    b.scatter_forward()
    return b.array.copy()


def contact_pressure(
    points,
    normal_force: np.ndarray,
    *,
    quadrature_degree: int = 2,
    configuration: str = "reference",
    areas: np.ndarray | None = None,
) -> ContactPressure:
    """p_j = f_n,j / A_j at a contact's point set on an FEM body (module docstring):
    ``points`` a point set of :mod:`artifem.contact_points` whose ``mesh_body`` is the FEM
    body (a reduced body's full body), ``normal_force`` (len(points),) its normal forces,
    as a contact's ``normal_forces`` gives them (``Scene.contact_pressure`` does both;
    A_j: :func:`boundary_areas`, or ``areas``, its result computed before)."""
    body = getattr(points, "mesh_body", None)
    if body is None:
        raise InputError(
            f"a contact pressure is for FEM bodies' nodes; these points have no "
            f"FEM mesh ({type(points).__name__})"
        )
    if areas is None:
        areas = boundary_areas(
            body, quadrature_degree=quadrature_degree, configuration=configuration
        )
    dofs = np.asarray(points.dofs)
    area = areas[dofs]
    if np.any(area <= 0):
        bad = np.asarray(points.labels)[area <= 0][:10].tolist()
        raise InputError(
            f"FemBody {body.name!r}: nodes {bad} have no boundary area (not on an exterior facet)"
        )
    pressure = np.asarray(normal_force, dtype=float) / area
    nodal = np.zeros(areas.shape)
    nodal[dofs] = pressure
    return ContactPressure(np.asarray(points.labels), pressure, area, nodal)
