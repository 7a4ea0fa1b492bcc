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
Schur complement, the step matrix kept: :func:`hold_linearized`), in the implicit
Newton solve on g(u) itself (Uzawa, p <- pi, an outer loop around Newton), in statics by
a Newton step on p in each iteration near the solution (Uzawa farther away:
:func:`artifem.integrators.solve_static`). kappa only sets how fast
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

import artifem.jit  # noqa: F401  (waits for another process's compile of a form)
from artifem.errors import InputError, StepFailed

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
        step_tol: the largest relative volume change a completed step may leave. A
            semi-implicit step holds the constraint linearized at its start, g + h G v = 0,
            so g(u) after it is off by O(h^2 |v|^2), corrected by the next step. A step
            that leaves more than ``step_tol`` (up to 8 % in a few tongue elements in a
            fast motion, 28 % when every muscle is switched fully on at once, against at
            most 0.06 % over a speech motion) is projected back onto g(u) = 0 (Newton with
            the step matrix kept: ``integrators._project_volumes``); one still off after
            that counts as failed, and the scene retries it (``Scene.fallback``, then
            halving) instead of going on from a state no step recovers from.
        projections: at most this many Newton iterations of that projection per step (each
            squares the violation: 9e-2, 2.5e-3, 2.0e-6 on a spun cube); 0 turns it off.
    """

    kappa: float
    tol: float = 1e-6
    max_updates: int = 50
    step_tol: float = 1e-2
    projections: int = 3

    def __post_init__(self):
        if not (np.isfinite(self.kappa) and self.kappa > 0):
            raise InputError(f"Incompressible: kappa must be > 0, got {self.kappa}")
        if not (np.isfinite(self.tol) and self.tol > 0):
            raise InputError(f"Incompressible: tol must be > 0, got {self.tol}")
        if not (np.isfinite(self.step_tol) and self.step_tol >= self.tol):
            raise InputError(
                f"Incompressible: step_tol must be >= tol ({self.tol}), got {self.step_tol}"
            )
        if int(self.projections) != self.projections or self.projections < 0:
            raise InputError(
                f"Incompressible: projections must be an integer >= 0, got {self.projections}"
            )
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
            raise InputError(
                f"FemBody {body.name!r}: hard incompressibility on "
                f"{body.cell_name!r} cells is not supported"
            )
        self.Q = fem.functionspace(body.mesh, family)
        #: pi = p - kappa g / V, the augmented energy's current pressure (its force G^T pi)
        self.pressure = fem.Function(self.Q, name="augmented pressure")
        #: the multipliers p: the pressures (Pa, > 0 in compression) that hold the volumes,
        #: the field to look at (equal to pi once g = 0)
        self.p = fem.Function(self.Q, name="pressure")
        #: the pressure of the geometric tangent -sum_i pi_i d^2 g_i: pi (the exact
        #: tangent, Newton), or p in a linearized step (see :meth:`assemble`)
        self.geometric = fem.Function(self.Q)
        imap = self.Q.dofmap.index_map
        self.n_owned = imap.size_local
        self.updates = 0  # multiplier updates in the last step
        self._compiled = None

    # ---- forms -------------------------------------------------------------

    def residual_term(self, F):
        """UFL integrand -pi J whose derivative is the body's residual term -G^T pi
        (pi held fixed, see the module docstring)."""
        return -self.pressure * ufl.det(F)

    def geometric_term(self, F):
        """UFL integrand -pi_g J whose second derivative is the geometric tangent."""
        return -self.geometric * ufl.det(F)

    def measure(self):
        return ufl.Measure(
            "dx", domain=self.body.mesh, metadata={"quadrature_degree": self.body.quadrature_degree}
        )

    def compile(self) -> None:
        body = self.body
        dx = self.measure()
        q = ufl.TestFunction(self.Q)
        du = ufl.TrialFunction(body.V)
        J = ufl.det(body.kinematics())
        c = {
            "g": fem.form((J - 1.0) * q * dx),
            "G": fem.form(ufl.derivative(J * q * dx, body.u, du)),
        }
        volume = fem_petsc.assemble_vector(fem.form(q * dx))
        volume.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        self.volume = volume.array[: self.n_owned].copy()
        if self.volume.size and self.volume.min() <= 0:
            raise InputError(
                f"FemBody {body.name!r}: an element of zero or negative volume "
                "(hard incompressibility needs positive reference volumes)"
            )
        volume.destroy()
        self.g = fem_petsc.create_vector(self.Q)
        self.G = fem_petsc.create_matrix(c["G"])
        self.D = PETSc.Mat().createAIJ(
            ((self.n_owned, None), (self.n_owned, None)), nnz=1, comm=body.mesh.comm
        )
        start = self.Q.dofmap.index_map.local_range[0]
        rows = np.arange(start, start + self.n_owned, dtype=PETSc.IntType)
        for i, r in enumerate(rows):
            self.D.setValue(r, r, self.kappa / self.volume[i])
        self.D.assemble()
        self.GtDG = None
        self._compiled = c

    # ---- evaluation --------------------------------------------------------

    def assemble(self, tangent: bool, linearized: bool = False) -> None:
        """g and G at the body's current u; pi = p - kappa g / V into ``pressure``;
        with ``tangent``, G^T D G too (D = diag kappa / V_i). Before the body's forms.

        ``linearized`` (a semi-implicit step): the geometric tangent takes the
        multipliers p instead of pi. Both are the constraint force's own multiplier once
        g = 0; at the start of a semi-implicit step g is the last step's O(h^2) drift,
        and pi = p - kappa g / V would make the step depend on kappa (the step's
        constraint force is G^T (p + dp) whatever kappa: module docstring)."""
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
        source = self.p if linearized else self.pressure
        self.geometric.x.array[:] = source.x.array
        if tangent:
            self.G.zeroEntries()
            fem_petsc.assemble_matrix(self.G, c["G"], bcs=self.body.bcs)
            self.G.assemble()
            if self.GtDG is None:
                self.GtDG = self.D.PtAP(self.G)
            else:
                self.D.PtAP(self.G, self.GtDG)

    def at_current_state(self, rows: bool = False) -> None:
        """g at the body's current u; with ``rows``, G too (a projection's rows: the
        check that comes first, every step, needs only g)."""
        self.assemble(tangent=rows)

    def violation(self, g: np.ndarray | None = None) -> float:
        """max_i |g_i| / V_i over every rank (of the assembled g, or of ``g``)."""
        g = self.g.array[: self.n_owned] if g is None else g
        local = float(np.abs(g / self.volume).max()) if g.size else 0.0
        return self.body.mesh.comm.allreduce(local, op=MPI.MAX)

    def describe(self, g: np.ndarray | None = None, count: int = 5) -> str:
        """Where the constraint is worst (collective): its element(s) (Q1/P0) or node
        patch(es) (nodal pressure) by input index, with their relative volume change."""
        g = self.g.array[: self.n_owned] if g is None else g
        ratio = np.abs(g / self.volume) if g.size else np.zeros(0)
        order = np.argsort(-ratio)[:count]
        dofs = self.Q.dofmap.list  # cell -> pressure dof(s)
        if dofs.shape[1] == 1:  # one per element
            cell_of = np.empty(self.n_owned, dtype=np.int32)
            owned = dofs[:, 0] < self.n_owned
            cell_of[dofs[owned, 0]] = np.flatnonzero(owned)
            ids, what = self.body.input_cell_index(cell_of[order]), "element(s)"
        else:  # nodal: the geometry's node ids
            node_of = np.empty(dofs.max() + 1, dtype=np.int64)
            node_of[dofs.reshape(-1)] = self.body.mesh.geometry.dofmaps[0].reshape(-1)
            ids = self.body.mesh.geometry.input_global_indices[node_of[order]]
            what = "node patch(es)"
        found = sorted(
            sum(
                self.body.mesh.comm.allgather(
                    [(float(ratio[k]), int(i)) for k, i in zip(order, ids)]
                ),
                [],
            ),
            reverse=True,
        )[:count]
        shown = ", ".join(f"{i} ({v:.1e})" for v, i in found)
        return (
            f"FemBody {self.body.name!r}: element volumes off by more than "
            f"{self.spec.tol:g} at {what} (input index, relative volume change) {shown}"
        )

    def step_failure(self) -> str | None:
        """After a step (collective): None while max_i |g_i| / V_i <= ``step_tol``, else
        where it is not (:meth:`describe`)."""
        self.assemble(tangent=False)
        if self.violation() <= self.spec.step_tol:
            return None
        return self.describe().replace(
            f"more than {self.spec.tol:g}", f"more than the step's {self.spec.step_tol:g}"
        )

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

    def linearized(self, v: PETSc.Vec, h: float) -> np.ndarray:
        """c = g + h G v (owned rows): the constraint at the end of a semi-implicit step
        with velocity v (g and G as last assembled)."""
        c = self.g.duplicate()
        self.G.mult(v, c)
        out = self.g.array[: self.n_owned] + h * c.array[: self.n_owned]
        c.destroy()
        return out

    def force_of(self, dp: np.ndarray, h: float, out: PETSc.Vec) -> None:
        """out = h G^T dp: the change of h f when the pressures change by dp."""
        d = self.g.duplicate()
        d.array[: self.n_owned] = dp
        self.G.multTranspose(d, out)
        out.scale(h)
        d.destroy()

    def rate_of(self, y: PETSc.Vec, h: float) -> np.ndarray:
        """h G y (owned rows): the change of c when the velocity changes by y."""
        c = self.g.duplicate()
        self.G.mult(y, c)
        out = h * c.array[: self.n_owned]
        c.destroy()
        return out

    # The same three on numpy arrays of the body's local dofs (serial: owned and ghost
    # rows), as the coupled island holds them (artifem.scene.layout.Layout.hold_volumes).

    def linearized_rows(self, v: np.ndarray, h: float) -> np.ndarray:
        return self.linearized(self._as_vec(v), h)

    def force_rows(self, dp: np.ndarray, h: float) -> np.ndarray:
        out = self.body.v.x.petsc_vec.duplicate()
        self.force_of(dp, h, out)
        rows = out.array.copy()
        out.destroy()
        return rows

    def rate_rows(self, y: np.ndarray, h: float) -> np.ndarray:
        return self.rate_of(self._as_vec(y), h)

    @staticmethod
    def _as_vec(array: np.ndarray) -> PETSc.Vec:
        return PETSc.Vec().createWithArray(
            np.array(array, dtype=PETSc.ScalarType), comm=PETSc.COMM_SELF
        )

    def add_to_pressures(self, dp: np.ndarray) -> None:
        n = self.n_owned
        for f in (self.p, self.pressure):
            f.x.array[:n] += dp
            f.x.scatter_forward()

    def pressure_range(self) -> tuple[float, float]:
        """(min, max) of the pressures p over every rank."""
        a = self.p.x.array[: self.n_owned]
        comm = self.body.mesh.comm
        return (
            comm.allreduce(float(a.min()) if a.size else np.inf, op=MPI.MIN),
            comm.allreduce(float(a.max()) if a.size else -np.inf, op=MPI.MAX),
        )


def hold_linearized(
    constraints: list[VolumeConstraint],
    c0: list[np.ndarray],
    respond,
    accept,
    comm,
    inexact: int | None = None,
    stop_when_indefinite: bool = False,
) -> int | None:
    """The linearized constraints of a semi-implicit step, c = c0 + S dp = 0 to each one's
    ``tol``, for the pressure changes dp of one or more bodies stepped together:

        S dp = -c0,    S = h^2 G A^-1 G^T  (A the step matrix, with whatever couples them),

    by conjugate gradients preconditioned by the augmentation's diag(kappa / V_i) (its
    Richardson iteration is the plain Uzawa update p -= kappa c / V, which stalls on the
    near-dependent rows of Q1/P0 next to fixed nodes: 50 updates were not enough on the
    tongue; CG takes a median 1-2). ``respond(d)`` (a list, one array per constraint)
    solves once with the step matrix for the force change h G^T d and returns S d;
    ``accept(alpha)`` adds alpha times that last velocity response to the step's
    velocities. S is symmetric when A is; for a non-conservative body (follower
    pressures) CG still reduces c in practice. The pressures are updated. Returns the
    iterations; raises StepFailed naming the worst elements when ``max_updates`` of some
    constraint is reached first. Where the step matrix is indefinite (a tangent that lost
    its stability, e.g. a full excitation at the first step), S is too and CG breaks down:
    :func:`_conjugate_residuals` takes over. ``inexact=k`` (a Newton iteration, whose
    linearization is only as good as its iterate): at most k iterations and no error; the
    Newton loop and the pressure updates around it make the constraint hold in the end.
    ``stop_when_indefinite``: at such a breakdown return None instead (what CG had
    accepted stays applied: the caller undoes it), for a caller with a better fallback.
    """
    weight = [vc.kappa / vc.volume for vc in constraints]
    r = [-c for c in c0]  # residual of S x = -c0 at x = 0
    x = [np.zeros_like(c) for c in c0]
    z = [w * ri for w, ri in zip(weight, r)]
    d = [zi.copy() for zi in z]
    rz = comm.allreduce(sum(float(ri @ zi) for ri, zi in zip(r, z)))
    limit = min(vc.spec.max_updates for vc in constraints) if inexact is None else inexact
    iterations = 0
    try:
        while any(vc.violation(-ri) > vc.spec.tol for vc, ri in zip(constraints, r)):
            iterations += 1
            if iterations > limit:
                if inexact is not None:
                    return iterations - 1
                raise StepFailed(_worst(constraints, r) + f" after {limit} pressure iterations")
            Sd = respond(d)
            dSd = comm.allreduce(sum(float(di @ si) for di, si in zip(d, Sd)))
            if not dSd > 0:  # S is indefinite (so is the step matrix): CR from here
                if stop_when_indefinite:
                    return None
                return _conjugate_residuals(
                    constraints,
                    r,
                    x,
                    weight,
                    respond,
                    accept,
                    comm,
                    iterations,
                    limit,
                    inexact is not None,
                )
            alpha = rz / dSd
            accept(alpha)
            for k in range(len(constraints)):
                x[k] += alpha * d[k]
                r[k] -= alpha * Sd[k]
                z[k] = weight[k] * r[k]
            rz, rz_old = comm.allreduce(sum(float(ri @ zi) for ri, zi in zip(r, z))), rz
            d = [zi + (rz / rz_old) * di for zi, di in zip(z, d)]
        return iterations
    finally:
        for vc, xk in zip(constraints, x):
            vc.add_to_pressures(xk)
            vc.updates = iterations


def _worst(constraints: list[VolumeConstraint], r: list[np.ndarray]) -> str:
    """:meth:`VolumeConstraint.describe` of every constraint still off (c = -r)."""
    return "; ".join(
        vc.describe(-rk) for vc, rk in zip(constraints, r) if vc.violation(-rk) > vc.spec.tol
    )


def _conjugate_residuals(
    constraints,
    r,
    x,
    weight,
    respond,
    accept,
    comm,
    iterations: int,
    limit: int,
    inexact: bool = False,
) -> int:
    """Preconditioned conjugate residuals (Saad, Iterative Methods, alg. 6.20) on S dp = r
    from where :func:`hold_linearized`'s CG broke down: like CG one S product (one solve) per
    iteration with the residual kept, but for symmetric indefinite S. The velocities of the
    pressure change it finds come from one more solve at the end. ``r`` and ``x`` are
    updated in place; returns the total iteration count (``inexact``: stops without an
    error at ``limit`` or a breakdown)."""

    def dot(a, b):
        return comm.allreduce(sum(float(ai @ bi) for ai, bi in zip(a, b)))

    start = [xi.copy() for xi in x]
    z = [w * ri for w, ri in zip(weight, r)]
    Sz = respond(z)
    p, Sp = [zi.copy() for zi in z], [si.copy() for si in Sz]
    zSz = dot(z, Sz)
    while any(vc.violation(-ri) > vc.spec.tol for vc, ri in zip(constraints, r)):
        iterations += 1
        MSp = [w * si for w, si in zip(weight, Sp)]
        denominator = dot(Sp, MSp)
        if iterations > limit or not denominator > 0 or zSz == 0:
            if inexact:
                iterations -= 1
                break
            why = (
                f"after {limit} pressure iterations"
                if iterations > limit
                else "(the pressure iteration broke down)"
            )
            raise StepFailed(
                _worst(constraints, r) + f" {why}; the step matrix is not "
                "positive definite (the tangent lost its stability)"
            )
        alpha = zSz / denominator
        for k in range(len(constraints)):
            x[k] += alpha * p[k]
            r[k] -= alpha * Sp[k]
            z[k] -= alpha * MSp[k]
        Sz = respond(z)
        zSz, zSz_old = dot(z, Sz), zSz
        beta = zSz / zSz_old
        p = [zi + beta * pi for zi, pi in zip(z, p)]
        Sp = [si + beta * spi for si, spi in zip(Sz, Sp)]
    respond([xi - si for xi, si in zip(x, start)])
    accept(1.0)
    return iterations
