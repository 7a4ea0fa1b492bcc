"""Hertz contact check: an FEM hemisphere pressed on a rigid plane (docs/contact.md).

The lower half of a sphere (radius R, centre (0, 0, R)) rests with its pole on the plane
z = 0 (:class:`~artifem.multibody.contact.PlaneContact`). Its flat face z = R is clamped
and moved down by delta (displacement control): the Scene's statics cannot hold a body
that only a contact holds (its first active-set trial is singular, docs/contact.md), and
a symmetry plane (a node fixed in some components) is not taken by the Scene yet, so the
load is the reaction of the plane, sum f_n, and delta is found by secant iterations on
log F = k log delta + c (Hertz: k = 3/2) until sum f_n is the target force. The clamp is
R away from the contact, whose radius a is 0.14 R: the contact zone sees the total force
and the local curvature only (Saint-Venant), which is what Hertz's closed form takes:

    E* = E / (1 - nu^2),  a = (3 F R / (4 E*))^(1/3),  p0 = 3 F / (2 pi a^2),
    p(r) = p0 sqrt(1 - r^2 / a^2).

The mesh (gmsh, P1 tetrahedra) has size ``h_pole`` within ``refine_radius`` of the pole
and grows to ``h_far``. Measured from the contact forces f_i at the nodes' reference
radii r_i (:func:`measure`): the radius from the second moment of the forces (Hertz:
sum f r^2 / sum f = 2 a^2 / 5, an integral that converges with the mesh), the radius of
the outermost pressing node (quantized by the node spacing), and the peak nodal pressure
p = f / A (``Scene.contact_pressure``) at the pole.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from mpi4py import MPI

import artifem as af

R, E, NU, FORCE = 0.01, 1e5, 0.45, 0.05


def hertz(force: float = FORCE, radius: float = R, young: float = E, poisson: float = NU):
    """(a, p0, delta) of Hertz's sphere on a rigid plane (module docstring); delta = a^2 / R."""
    e_star = young / (1.0 - poisson**2)
    a = (3.0 * force * radius / (4.0 * e_star)) ** (1.0 / 3.0)
    return a, 3.0 * force / (2.0 * math.pi * a * a), a * a / radius


def hemisphere_mesh(h_pole: float, h_far: float, refine_radius: float, radius: float = R):
    """The lower hemisphere of radius ``radius`` centred at (0, 0, radius), P1 tetrahedra
    by gmsh: size h_pole within refine_radius of the pole (0, 0, 0), growing linearly to
    h_far at 3 refine_radius."""
    import gmsh
    from dolfinx.io import gmsh as dgmsh

    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("hemisphere")
        gmsh.model.occ.addSphere(0.0, 0.0, radius, radius, 1, -math.pi / 2, 0.0)
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(3, [1], 1)
        pole = [
            tag
            for dim, tag in gmsh.model.getEntities(0)
            if np.linalg.norm(gmsh.model.getValue(0, tag, [])) < 1e-9 * radius
        ]
        if len(pole) != 1:
            raise RuntimeError(f"hemisphere_mesh: expected one vertex at the pole, got {pole}")
        field = gmsh.model.mesh.field
        dist = field.add("Distance")
        field.setNumbers(dist, "PointsList", pole)
        thr = field.add("Threshold")
        field.setNumber(thr, "InField", dist)
        field.setNumber(thr, "SizeMin", h_pole)
        field.setNumber(thr, "SizeMax", h_far)
        field.setNumber(thr, "DistMin", refine_radius)
        field.setNumber(thr, "DistMax", 3.0 * refine_radius)
        field.setAsBackgroundMesh(thr)
        for opt in (
            "Mesh.MeshSizeFromPoints",
            "Mesh.MeshSizeFromCurvature",
            "Mesh.MeshSizeExtendFromBoundary",
        ):
            gmsh.option.setNumber(opt, 0)
        gmsh.option.setNumber("Mesh.Optimize", 1)
        gmsh.model.mesh.generate(3)
        return dgmsh.model_to_mesh(gmsh.model, MPI.COMM_SELF, 0, gdim=3).mesh
    finally:
        gmsh.finalize()


@dataclass
class HertzResult:
    """One displacement-controlled solve at the target force (module docstring)."""

    h_pole: float
    nodes: int
    delta: float  # the flat face's displacement (m, downwards)
    force: float  # sum f_n (N)
    radius_moment: float  # sqrt(5/2 sum f r^2 / sum f) (m)
    radius_outer: float  # the outermost pressing node's reference radius (m)
    fit_radius: float  # a of the fit of p0 sqrt(1 - r^2 / a^2) to f_n / A (m)
    fit_pressure: float  # p0 of that fit (Pa)
    fit_scatter: float  # the area-weighted rms of f_n / A about the fit, / p0
    peak_pressure: float  # the largest nodal pressure max f_n / A (Pa)
    pressing: int  # nodes with f_n > 0
    static_solves: int  # Scene.solve_static calls of the secant
    newton_iterations: int  # their Newton iterations, in all


class HertzModel:
    """The scene: the hemisphere (neo-Hookean, E, nu), its clamped flat face, the plane.
    ``margin`` (of the contact) must exceed the approach delta (about 0.18 mm): the first
    solve starts from the flat face moved down and every other node in place."""

    def __init__(
        self,
        h_pole: float,
        h_far: float = 2.5e-3,
        refine_radius: float = 2.5e-3,
        margin: float = 3e-4,
    ):
        self.h_pole = h_pole
        msh = hemisphere_mesh(h_pole, h_far, refine_radius)
        self.body = af.FemBody(
            msh, af.NeoHookean.from_young_poisson(E, NU), 1000.0, name="hemisphere"
        )
        self.top = self.body.find_nodes(lambda x: np.isclose(x[2], R, atol=1e-9 * R))
        self.contact = af.PlaneContact(
            self.body, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), tolerance=1e-9, margin=margin
        )
        self.scene = af.Scene()
        self.scene.add(self.body, self.contact)
        self.newton = 0

    def press(self, delta: float) -> float:
        """Clamp the flat face at z = R - delta, solve the statics; sum f_n (N)."""
        self.body.fix_nodes(
            self.top,
            displacement=lambda x: np.vstack(
                [np.zeros(x.shape[1]), np.zeros(x.shape[1]), np.full(x.shape[1], -delta)]
            ),
        )
        self.newton += sum(self.scene.solve_static())
        return float(self.scene.contact_forces(self.contact).normal.sum())

    def solve(self, force: float = FORCE, rtol: float = 1e-4, max_iterations: int = 12):
        """Secant on log F(log delta) to sum f_n = force to ``rtol`` (module docstring);
        the number of static solves."""
        d0 = 1.2 * hertz(force)[2]
        f0 = self.press(d0)
        d1 = d0 * (force / f0) ** (2.0 / 3.0)
        for it in range(1, max_iterations + 1):
            f1 = self.press(d1)
            if abs(f1 / force - 1.0) < rtol:
                return it + 1
            k = math.log(f1 / f0) / math.log(d1 / d0)
            d0, f0 = d1, f1
            d1 = d1 * (force / f1) ** (1.0 / k)
        raise RuntimeError(f"Hertz: the secant did not reach {force} N: {f1} N at delta {d1}")

    def measure(self, static_solves: int = 0) -> HertzResult:
        """The radii and pressures of the last solve (module docstring), at the nodes'
        reference radii r = |(x, y)|."""
        forces = self.scene.contact_forces(self.contact)
        cp = self.scene.contact_pressure(self.contact)[self.body.name]
        rows = np.isin(cp.points, forces.points)  # the nodes that had rows
        pressure, area = cp.pressure[rows], cp.area[rows]
        x = self.body.V.tabulate_dof_coordinates()[self.body.local_dofs(cp.points[rows])]
        r = np.hypot(x[:, 0], x[:, 1])
        f = pressure * area
        on = f > 1e-12 * f.max()
        (a_fit, p_fit), scatter = fit_hertz(r, pressure, area, *hertz(float(f.sum()))[:2])
        delta = -float(self.body.u.x.array.reshape(-1, 3)[self.body.local_dofs(self.top[:1]), 2][0])
        return HertzResult(
            h_pole=self.h_pole,
            nodes=int(self.body.mesh.geometry.index_map().size_global),
            delta=delta,
            force=float(f.sum()),
            radius_moment=float(math.sqrt(2.5 * (f * r * r).sum() / f.sum())),
            radius_outer=float(r[on].max()),
            fit_radius=a_fit,
            fit_pressure=p_fit,
            fit_scatter=scatter,
            peak_pressure=float(pressure.max()),
            pressing=int(on.sum()),
            static_solves=static_solves,
            newton_iterations=self.newton,
        )


def fit_hertz(r: np.ndarray, p: np.ndarray, area: np.ndarray, a0: float, p0: float):
    """((a, p0), scatter): the Hertz profile p0 sqrt(1 - r^2 / a^2) (0 beyond a) nearest to
    the nodal pressures p at radii r in the area-weighted least squares sum A (p - p(r))^2
    over every node with a contact row (those beyond the zone included, at p = 0), from
    (a0, p0); scatter: the weighted rms of the residual over p0."""
    from scipy.optimize import least_squares

    w = np.sqrt(area / area.sum())

    def residual(x):
        a, q = x
        return w * (p - q * np.sqrt(np.clip(1.0 - (r / a) ** 2, 0.0, None)))

    sol = least_squares(residual, [a0, p0], x_scale=[a0, p0])
    a, q = (float(v) for v in sol.x)
    return (a, q), float(np.sqrt(np.sum(residual(sol.x) ** 2)) / q)


def run(h_pole: float, **kwargs) -> HertzResult:
    """Build, press to FORCE, measure."""
    model = HertzModel(h_pole, **kwargs)
    iterations = model.solve()
    return model.measure(iterations)
