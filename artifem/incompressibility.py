"""Hard incompressibility of an FEM body: element (or node) volumes kept by an augmented Lagrangian.

The constraint, one row per pressure dof i (Q1/P0 mean dilatation on hexahedra and
prisms: q_i the indicator of element i; the nodal-averaged pressure on P1 tetrahedra,
whose one-constant-per-element version locks: q_i the P1 hat function of node i),

    g_i(u) = int q_i (J - 1) dX = 0,          J = det(I + grad u),

is enforced with multipliers p_i (the pressure, > 0 in compression: the Cauchy stress
gains -p I) by the augmented energy added to the body's potential,

    W(u; p) = sum_i [ -p_i g_i + kappa / (2 V_i) g_i^2 ],      V_i = int q_i dX,

whose force is f = G^T pi with G = dg/du and pi_i = p_i - kappa g_i / V_i (the
current pressure), and whose tangent is K = kappa G^T V^-1 G - sum_i pi_i d^2 g_i.
The multipliers are updated until max_i |g_i| / V_i <= ``tol``: within a semi-implicit
step on the linearized constraint g + h G v+ (conjugate gradients on the pressure's
Schur complement, the step matrix kept: :meth:`VolumeConstraint.hold_linearized`), in
the implicit and static Newton solves on g(u) itself (Uzawa, p <- pi, an outer loop
around Newton). kappa only sets how fast
that converges (and how well the step matrix is conditioned): the answer does not
depend on it, unlike a penalty's, whose volume error is pressure / kappa.

The rank-one blocks kappa / V_i (dg_i)(dg_i)^T are a product of two integrals, which a
UFL form cannot express: they are G^T D G, formed by PETSc's sparse product (MatPtAP)
from the assembled G. Everything else is UFL (``ufl.derivative`` of int pi J dX).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from dolfinx import fem
from dolfinx.fem import petsc as fem_petsc

from artifem.errors import InputError

#: pressure space per cell type (see the module docstring)
PRESSURE_SPACE = {"hexahedron": ("DG", 0), "prism": ("DG", 0), "tetrahedron": ("Lagrange", 1)}


@dataclass(frozen=True)
class Incompressible:
    """Hard element-wise incompressibility (the module docstring's constraint).

    Args:
        kappa: augmentation modulus (Pa) of the augmented Lagrangian; about 10-100
            times the shear modulus. It does not change the answer, only how many
            multiplier updates a step needs and the conditioning of the step matrix.
        tol: the constraint holds to max_i |g_i| / V_i <= tol (relative volume
            change of each element, or of each node's patch on tetrahedra).
        max_updates: multiplier updates per step (or static load step) before the
            step is declared failed (and halved by the scene).
    """

    kappa: float
    tol: float = 1e-6
    max_updates: int = 50

    def __post_init__(self):
        if not (np.isfinite(self.kappa) and self.kappa > 0):
            raise InputError(f"Incompressible: kappa must be > 0, got {self.kappa}")
        if not (np.isfinite(self.tol) and self.tol > 0):
            raise InputError(f"Incompressible: tol must be > 0, got {self.tol}")
        if int(self.max_updates) < 1:
            raise InputError(f"Incompressible: max_updates must be >= 1, got {self.max_updates}")


class VolumeConstraint:
    """An :class:`Incompressible` bound to one FEM body: its pressure space, forms and state.

    ``body`` gives ``mesh``, ``u``, ``V``, ``cell_name``, ``quadrature_degree`` and its
    fixed-dof conditions ``bcs`` (bound by :meth:`compile`, called by the body's compile).
    """

    def __init__(self, body, spec: Incompressible):
        self.body, self.spec = body, spec
        self.kappa = float(spec.kappa)
        family = PRESSURE_SPACE.get(body.cell_name)
        if family is None:
            raise InputError(f"FemBody {body.name!r}: hard incompressibility on "
                             f"{body.cell_name!r} cells is not supported")
        self.Q = fem.functionspace(body.mesh, family)
        #: pi, the current pressure (Pa, > 0 in compression) per pressure dof
        self.pressure = fem.Function(self.Q, name="pressure")
        self.p = fem.Function(self.Q, name="multiplier")     # the multipliers p
        imap = self.Q.dofmap.index_map
        self.n_owned = imap.size_local
        self.updates = 0                # multiplier updates in the last step
        self._compiled = None

    # ---- forms -------------------------------------------------------------

    def residual_term(self, F):
        """UFL integrand -pi J of the body's residual energy: its derivative is -G^T pi,
        its second derivative -sum pi_i d^2 g_i (pi held fixed, see the module docstring)."""
        return -self.pressure * ufl.det(F)

    def measure(self):
        return ufl.Measure("dx", domain=self.body.mesh,
                           metadata={"quadrature_degree": self.body.quadrature_degree})

    def compile(self) -> None:
        body = self.body
        dx = self.measure()
        q = ufl.TestFunction(self.Q)
        du = ufl.TrialFunction(body.V)
        J = ufl.det(body.kinematics())
        c = {"g": fem.form((J - 1.0) * q * dx),
             "G": fem.form(ufl.derivative(J * q * dx, body.u, du))}
        volume = fem_petsc.assemble_vector(fem.form(q * dx))
        volume.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        self.volume = volume.array[:self.n_owned].copy()
        if self.volume.size and self.volume.min() <= 0:
            raise InputError(f"FemBody {body.name!r}: an element of zero or negative volume "
                             "(hard incompressibility needs positive reference volumes)")
        volume.destroy()
        self.g = fem_petsc.create_vector(self.Q)
        self.G = fem_petsc.create_matrix(c["G"])
        self.D = PETSc.Mat().createAIJ(((self.n_owned, None), (self.n_owned, None)), nnz=1,
                                       comm=body.mesh.comm)
        start = self.Q.dofmap.index_map.local_range[0]
        rows = np.arange(start, start + self.n_owned, dtype=PETSc.IntType)
        for i, r in enumerate(rows):
            self.D.setValue(r, r, self.kappa / self.volume[i])
        self.D.assemble()
        self.GtDG = None
        self._compiled = c

    # ---- evaluation --------------------------------------------------------

    def assemble(self, tangent: bool) -> None:
        """g and G at the body's current u; pi = p - kappa g / V into ``pressure``;
        with ``tangent``, G^T D G too (D = diag kappa / V_i). Before the body's forms."""
        if self._compiled is None:
            self.compile()
        c = self._compiled
        with self.g.localForm() as loc:
            loc.set(0.0)
        fem_petsc.assemble_vector(self.g, c["g"])
        self.g.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        n = self.n_owned
        self.pressure.x.array[:n] = self.p.x.array[:n] - self.kappa * self.g.array[:n] / self.volume
        self.pressure.x.scatter_forward()
        if tangent:
            self.G.zeroEntries()
            fem_petsc.assemble_matrix(self.G, c["G"], bcs=self.body.bcs)
            self.G.assemble()
            if self.GtDG is None:
                self.GtDG = self.D.PtAP(self.G)
            else:
                self.D.PtAP(self.G, self.GtDG)

    def violation(self, g: np.ndarray | None = None) -> float:
        """max_i |g_i| / V_i over every rank (of the assembled g, or of ``g``)."""
        g = self.g.array[:self.n_owned] if g is None else g
        local = float(np.abs(g / self.volume).max()) if g.size else 0.0
        return self.body.mesh.comm.allreduce(local, op=MPI.MAX)

    def energy(self) -> float:
        """W(u; p) at the assembled g (module docstring)."""
        n = self.n_owned
        g = self.g.array[:n]
        local = float(np.sum(-self.p.x.array[:n] * g + 0.5 * self.kappa * g * g / self.volume))
        return self.body.mesh.comm.allreduce(local)

    def update(self) -> float:
        """Uzawa on the nonlinear constraint: the violation of the assembled g, then p <- pi
        (call after the body was assembled at the new u)."""
        viol = self.violation()
        self.p.x.array[:] = self.pressure.x.array
        return viol

    def hold_linearized(self, v: PETSc.Vec, dv: PETSc.Vec, h: float, solve) -> int:
        """The semi-implicit step's constraint c = g + h G (v + dv) = 0, to ``tol``: dp and a
        velocity change h A^-1 G^T dp solve the pressure's Schur complement system

            S dp = -c,    S = h^2 G A^-1 G^T,

        by conjugate gradients preconditioned by the augmentation's diag(kappa / V_i)
        (its Richardson iteration is the plain Uzawa update p -= kappa c / V, which stalls
        on the near-dependent rows of Q1/P0 by the fixed nodes: 50 updates were not enough
        on the tongue). One solve with the step matrix A (``solve(rhs, x)``: A x = rhs, fixed
        rows zero) per iteration. S is symmetric when A is; for a non-conservative body
        (follower pressures) CG still reduces c in practice, and a step that does not reach
        ``tol`` in ``max_updates`` iterations fails (and is halved). p, ``pressure`` and ``dv``
        are updated; returns the iteration count."""
        n, comm = self.n_owned, self.body.mesh.comm
        c = self.g.duplicate()
        v_new = v.copy()
        v_new.axpy(1.0, dv)
        self.G.mult(v_new, c)
        r = -(self.g.array[:n] + h * c.array[:n])           # residual of S x = -c0, x = 0
        x = np.zeros(n)
        w, y = v.duplicate(), v.duplicate()
        weight = self.kappa / self.volume
        z = weight * r
        d = z.copy()
        rz = comm.allreduce(float(r @ z))
        iterations = 0
        try:
            while self.violation(-r) > self.spec.tol:
                iterations += 1
                if iterations > self.spec.max_updates:
                    return -1
                c.array[:n] = d
                self.G.multTranspose(c, w)                   # w = h G^T d
                w.scale(h)
                solve(w, y)                                  # y = A^-1 h G^T d
                self.G.mult(y, c)
                Sd = h * c.array[:n]
                dSd = comm.allreduce(float(d @ Sd))
                if not dSd > 0:
                    return -1
                alpha = rz / dSd
                x += alpha * d
                dv.axpy(alpha, y)
                r -= alpha * Sd
                z = weight * r
                rz, rz_old = comm.allreduce(float(r @ z)), rz
                d = z + (rz / rz_old) * d
            return iterations
        finally:
            self.p.x.array[:n] += x
            self.p.x.scatter_forward()
            self.pressure.x.array[:n] += x
            self.pressure.x.scatter_forward()
            self.updates = iterations
            for vec in (c, v_new, w, y):
                vec.destroy()

    def pressure_range(self) -> tuple[float, float]:
        """(min, max) of pi over every rank."""
        a = self.pressure.x.array[:self.n_owned]
        comm = self.body.mesh.comm
        return (comm.allreduce(float(a.min()) if a.size else np.inf, op=MPI.MIN),
                comm.allreduce(float(a.max()) if a.size else -np.inf, op=MPI.MAX))
