"""The scene (ArtiSynth's MechModel): components, controllers, and the step.

A :class:`System` holds dynamic components (each owns its coordinates and
velocities), controllers that change inputs between steps (excitation
schedules), and the list of attachments and bilateral constraints.

Components are full-order :class:`~artifem.fem_body.FemBody` objects (nodal
displacements, PETSc, a linear solver per body) and reduced
:class:`~artifem.reduction.reduced_body.ReducedFemBody` objects (u = u_bar + U q,
dense r x r, no PETSc in their step). Both are advanced by the same integrator
(``advance`` for full bodies, ``advance_reduced`` for reduced ones) and driven
by the same controllers: a reduced body shares its full body's excitation and
load-factor constants.

The step is organized by *islands*: sets of components coupled through
attachments (x_a = f(x_m), velocities G v_m, forces back as G^T f_a) or
constraints (Lagrange multipliers). Components in different islands do not
interact within a step, so each island is advanced by its own solve. With no
attachments every component is its own island; the coupled island solve
(P^T A P with the attachment prolongation P, KKT rows for joints) is where
attachments and joints plug in.

Robustness: after each step every component is checked for non-finite
coordinates or velocities and for det F <= 0 at its quadrature points (a
reduced body: at its m integration points only -- the energy sees nothing
else, so the mesh rebuilt from U q may invert elsewhere, see
``ReducedFemBody.full_mesh_inversion``). A failed step is undone and
retried as two steps of half the size, recursively up to ``max_halvings``
times; beyond that :class:`~artifem.fem_body.ElementInversionError` names the
time, the elements and the smallest det F.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from mpi4py import MPI

from artifem.errors import ElementInversionError, InputError, LinearSolveError, StepFailed
from artifem.fem_body import FemBody
from artifem.integrators import ImplicitEuler, SemiImplicitEuler, solve_static, solve_static_reduced
from artifem.linear_solver import DEFAULT_METHOD, LinearSolver
from artifem.reduction.reduced_body import ReducedFemBody

#: A dynamic component of a System.
Component = FemBody | ReducedFemBody

INTEGRATORS = {"semi-implicit": SemiImplicitEuler, "implicit": ImplicitEuler}

#: A controller sets inputs (excitations, loads) for the step from t0 to t1
#: (ArtiSynth's Controller.apply(t0, t1)).
Controller = Callable[["System", float, float], None]


class System:
    """A scene of dynamic components advanced together in time.

    Args:
        integrator: ``"semi-implicit"`` (ArtiSynth's default), ``"implicit"``,
            or an integrator object with ``advance(body, h, solver)`` (and
            ``advance_reduced(body, h)`` for reduced bodies).
        linear_solver: a method of :class:`~artifem.linear_solver.LinearSolver`.
        max_halvings: how many times a failing step may be halved.
    """

    def __init__(self, *, integrator="semi-implicit", linear_solver: str = DEFAULT_METHOD,
                 max_halvings: int = 4):
        if isinstance(integrator, str):
            if integrator not in INTEGRATORS:
                raise InputError(f"unknown integrator {integrator!r}; choose one of "
                                 f"{sorted(INTEGRATORS)}")
            integrator = INTEGRATORS[integrator]()
        self.integrator = integrator
        self.linear_solver_method = linear_solver
        self.max_halvings = max_halvings
        self.components: list[Component] = []
        self.controllers: list[Controller] = []
        self.attachments: list = []     # x_a = f(x_m) couplings (multibody issue)
        self.constraints: list = []     # bilateral joints (multibody issue)
        self.time = 0.0
        self.halvings = 0               # how many step halvings happened so far
        self.min_det_F = np.inf         # smallest det F seen after any completed step
        self._solvers: dict[str, LinearSolver] = {}

    def add(self, component: Component) -> Component:
        if any(c.name == component.name for c in self.components):
            raise InputError(f"a component named {component.name!r} is already in the system")
        if isinstance(component, ReducedFemBody) and not hasattr(self.integrator,
                                                                  "advance_reduced"):
            raise TypeError(f"integrator {type(self.integrator).__name__} has no "
                            f"advance_reduced(body, h) for the reduced body {component.name!r}")
        self.components.append(component)
        return component

    def add_controller(self, controller: Controller) -> None:
        self.controllers.append(controller)

    def islands(self) -> list[list[Component]]:
        """Groups of components coupled by attachments or constraints."""
        if self.attachments or self.constraints:
            raise NotImplementedError(
                "coupled islands (attachments, joints) are solved by the multibody layer")
        return [[c] for c in self.components]

    def solver_for(self, body: FemBody) -> LinearSolver:
        """The linear solver of a full-order body (reduced bodies solve densely)."""
        if not isinstance(body, FemBody):
            raise TypeError(f"{body.name!r} is not a full-order FemBody: it has no linear solver")
        if body.name not in self._solvers:
            self._solvers[body.name] = LinearSolver(body.mesh.comm, self.linear_solver_method,
                                                    V=body.V)
        return self._solvers[body.name]

    # ---- stepping ---------------------------------------------------------

    def step(self, dt: float) -> None:
        """Advance every island by dt (halving on failure, see module docstring)."""
        if not np.isfinite(dt) or dt <= 0:
            raise InputError(f"time step must be > 0, got {dt}")
        self._advance(dt, depth=0)

    def _advance(self, dt: float, depth: int) -> None:
        for controller in self.controllers:
            controller(self, self.time, self.time + dt)
        saved = [c.state() for c in self.components]
        failure = None
        try:
            for island in self.islands():
                for body in island:
                    self._advance_body(body, dt)
            failure = self._check_state()
        except (StepFailed, LinearSolveError) as exc:
            failure = str(exc)
        if failure is None:
            self.time += dt
            return
        for c, s in zip(self.components, saved):
            c.set_state(s)
        if depth >= self.max_halvings:
            self._raise_failure(failure, dt)
        self.halvings += 1
        self._advance(dt / 2, depth + 1)
        self._advance(dt / 2, depth + 1)

    def _advance_body(self, body: Component, dt: float) -> None:
        if isinstance(body, ReducedFemBody):
            self.integrator.advance_reduced(body, dt)
        else:
            self.integrator.advance(body, dt, self.solver_for(body))

    def _check_state(self) -> str | None:
        step_min = np.inf
        for body in self.components:
            finite = all(np.all(np.isfinite(a)) for a in body.state())
            comm = body.full.mesh.comm if isinstance(body, ReducedFemBody) else body.mesh.comm
            if not comm.allreduce(bool(finite), op=MPI.LAND):
                return f"non-finite coordinates or velocities in {body.name!r}"
            bad, min_det = body.inverted_elements()
            if bad.size or not np.isfinite(min_det):
                return f"inverted elements in {body.name!r}"
            step_min = min(step_min, min_det)
        self.min_det_F = min(self.min_det_F, step_min)
        return None

    def _raise_failure(self, failure: str, dt: float) -> None:
        """Leave the state at the start of the failed step and explain why."""
        detail = f"{failure}; step {dt:.3g} s after {self.max_halvings} halvings"
        for body in self.components:
            # Report the elements that invert when the smallest step is taken.
            saved = body.state()
            try:
                self._advance_body(body, dt)
                bad, min_det = body.inverted_elements()
            except (StepFailed, LinearSolveError):
                bad, min_det = body.inverted_elements()
            body.set_state(saved)
            if bad.size or min_det <= 0:
                raise ElementInversionError(self.time + dt, bad, min_det, detail, body=body.name)
        raise StepFailed(f"step failed at t = {self.time:.6g} s: {detail}")

    def solve_static(self, load_steps: int = 1, **kwargs) -> None:
        """Static equilibrium of every component (load increments of the load factor)."""
        for island in self.islands():
            for body in island:
                if isinstance(body, ReducedFemBody):
                    solve_static_reduced(body, load_steps=load_steps, **kwargs)
                else:
                    solve_static(body, self.solver_for(body), load_steps=load_steps, **kwargs)

    def energy(self) -> dict[str, float]:
        """Kinetic, potential and total energy summed over components."""
        T = sum(c.kinetic_energy() for c in self.components)
        V = sum(c.potential_energy() for c in self.components)
        return {"kinetic": T, "potential": V, "total": T + V}
