"""Contact pressure of an FEM body's nodes from the normal forces of its contact rows.

Each boundary node i that had a contact row carries the normal force f_n,i (N,
:class:`~artifem.multibody.contact.ContactForces`). Its pressure is that force over the
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
    """points: the input node indices that had contact rows (as ContactForces.points);
    pressure: (k,) f_n / A (Pa); area: (k,) their tributary areas A (m^2);
    nodal: the pressure at every local node, indexed like a scalar P1 function's dofs on the
    body's mesh (zero off the contact; ``fem.Function(...).x.array[:] = nodal``)."""

    points: np.ndarray
    pressure: np.ndarray
    area: np.ndarray
    nodal: np.ndarray


def boundary_areas(body: FemBody, *, quadrature_degree: int = 2,
                   configuration: str = "reference") -> np.ndarray:
    """A_i = int over the exterior facets of N_i dA, at every local node (owned and ghost),
    indexed by the body's block dofs (equal to a scalar P1 space's dofs on its mesh).

    ``configuration``: "reference" (dA) or "current" (da = J |F^-T N| dA with the body's
    displacement u). ``quadrature_degree``: of the facet integral (2 integrates the
    reference one exactly; the current one's J |F^-T N| is piecewise constant on P1)."""
    if configuration not in ("reference", "current"):
        raise InputError(f"boundary_areas: configuration must be 'reference' or 'current', "
                         f"got {configuration!r}")
    domain = body.mesh
    S = fem.functionspace(domain, ("Lagrange", 1))
    if not np.array_equal(S.dofmap.list, body.V.dofmap.list):
        raise InputError(f"FemBody {body.name!r}: its scalar P1 dofs differ from its block "
                         "dofs; the nodal areas cannot be indexed by node")
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


def contact_pressure(contact, forces, *, quadrature_degree: int = 2,
                     configuration: str = "reference") -> ContactPressure:
    """p_i = f_n,i / A_i at the nodes of ``forces`` (a contact's
    :class:`~artifem.multibody.contact.ContactForces`, e.g. ``scene.contact_forces(c)``)
    on ``contact.body``, a full FEM body (module docstring; A_i: :func:`boundary_areas`)."""
    body = contact.body
    if not isinstance(body, FemBody):
        raise InputError(f"contact {getattr(contact, 'name', contact)!r}: a contact pressure "
                         f"is for FEM bodies, got {type(body).__name__}")
    areas = boundary_areas(body, quadrature_degree=quadrature_degree,
                           configuration=configuration)
    points = np.asarray(forces.points, dtype=int)
    dofs = body.local_dofs(points)
    if dofs.size != points.size:
        raise InputError(f"FemBody {body.name!r}: contact forces name nodes not on this body")
    area = areas[dofs]
    if np.any(area <= 0):
        bad = points[area <= 0][:10].tolist()
        raise InputError(f"FemBody {body.name!r}: nodes {bad} have no boundary area (not on "
                         "an exterior facet)")
    pressure = np.asarray(forces.normal, dtype=float) / area
    nodal = np.zeros(areas.shape)
    nodal[dofs] = pressure
    return ContactPressure(points, pressure, area, nodal)
