"""Wheels that slide: the unconstrained chain with Coulomb friction across each wheel (a reference model).

The paper's model (eqs. 26-27) holds each wheel to zero lateral velocity with whatever force that
takes. A rubber wheel holds at most mu m_k g (N) sideways; past that it slides, and friction of
that size opposes the slide (anisotropic Coulomb friction: Transeth et al. 2008, Liljebaeck et al.
2010). Here the snake is the unconstrained planar chain of eqs. 22-25 (coordinates
q = (theta_1..theta_n, x, y), velocities qdot: n + 2 degrees of freedom) and wheel k's lateral
velocity v_k = A_k qdot (eq. 26's row, m/s) meets the force

    f_k = -mu m_k g v_k / sqrt(v_k^2 + v_eps^2)          (N, along e_k_perp)

Coulomb friction regularised over ``slip_speed`` v_eps (m/s): nearly mu m_k g once a wheel slides
faster than a few v_eps, and a stiff viscous grip below, so that the friction force is a smooth
function of the state. Lagrange's equations then read

    M qddot = Q - B + A^T f                              (eqs. 24-25, 27 with lambda = f)

As mu grows the lateral velocities vanish and the trajectories converge to the no-slip model of
eq. 27 (tested). Along the wheels (rolling resistance), at the joints (motor, damping, limit
barrier) the loads are those of the env's physics (``lagrange.generalized_forces``, the motor of
:mod:`.motor`, the barrier of the compiled kernels); the traction limit is not applied: here the
wheels slide instead. The model is stiff (a lateral time constant of about v_eps / (mu g)), so it
is integrated by an implicit method (scipy's LSODA) control step by control step, in numpy: a
reference for measurements, thousands of times slower than the env's kernels.
"""

from __future__ import annotations

import math

import numpy as np

from . import compiled, sliding_step
from .lagrange import (
    _bias_from_geometry,
    _inertia_from_jacobians,
    constraint_matrix,
    generalized_forces,
    lever_arms,
    link_jacobians,
    rotor_inertia_matrix,
    unit_vectors,
)
from .model import GRAVITY, SnakeModel
from .motor import motor_torque_reference



class SlidingWheels:
    """The sliding-wheel model of one snake (module doc).

    Args:
        model: links and dampings (:class:`SnakeModel`).
        friction: mu, the wheels' lateral friction coefficient (dimensionless, > 0).
        slip_speed: v_eps (m/s, > 0), the regularisation of Coulomb's law.
        stall_torque, no_load_speed, torque_limit: the joint motor (N m, rad/s, N m; :mod:`.motor`);
            inf, inf, inf for an ideal torque source.
        joint_limit, limit_stiffness, limit_damping: the joint-limit barrier (rad, N m/rad,
            N m s/rad) as the env's kernels apply it; joint_limit 0 for none.
        rotor_inertia: (n-1,) reflected rotor inertias (kg m^2) or None.
        back_emf_braking: a motor back-driven past its current limit brakes with its back-EMF's torque
            (:mod:`.motor`; the env's physics from v4); False: braking capped at torque_limit.
    """

    def __init__(self, model: SnakeModel, friction: float, slip_speed: float = 1e-3,
                 stall_torque: float = math.inf, no_load_speed: float = math.inf, torque_limit: float = math.inf,
                 joint_limit: float = 0.0, limit_stiffness: float = 0.0, limit_damping: float = 0.0,
                 rotor_inertia=None, back_emf_braking: bool = False):
        for name, value in (("friction", friction), ("slip_speed", slip_speed)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
        self.model = model
        self.n = model.n_links
        m, h, inertia, _, _ = model.parameters(np.float64)
        self.mass, self.inertia = m, inertia
        self.lever = lever_arms(h)
        self.grip = friction * GRAVITY * m  # N, the most each wheel holds sideways
        self.slip_speed = float(slip_speed)
        self.motor = (float(stall_torque), float(no_load_speed), float(torque_limit))
        self.back_emf_braking = bool(back_emf_braking)
        self.limit = (float(joint_limit), float(limit_stiffness), float(limit_damping))
        self.rotor = (np.zeros((self.n + 2, self.n + 2)) if rotor_inertia is None
                      else rotor_inertia_matrix(np.asarray(rotor_inertia, dtype=np.float64), self.n))
        self._constants = None
        self.solver_stats = None

    # ------------------------------------------------------------ loads
    def joint_torques(self, command, q, qdot):
        """The joints' torques (N m) before damping: the motor's for ``command`` (N m), less the barrier."""
        n = self.n
        phi = q[1:n] - q[:n - 1]
        phidot = qdot[1:n] - qdot[:n - 1]
        stall, no_load, t_max = self.motor
        T = np.asarray(command, dtype=np.float64)
        if t_max < math.inf:
            T = motor_torque_reference(T, phidot, stall, no_load, t_max, self.back_emf_braking)
        limit, k_limit, c_limit = self.limit
        if limit > 0.0:  # as compiled.rk4_stage_lanes: a ramped, capped barrier beyond |phi| > limit
            excess = np.where(phi > limit, phi - limit, phi + limit)
            d = np.abs(excess)
            depth = np.minimum(d * compiled.inverse_room(limit), compiled.BARRIER_CAP)
            ramp = d / (d + compiled.LIMIT_RAMP)
            barrier = ramp * (k_limit * excess / (1.0 - depth) + c_limit * phidot)
            T = np.where(np.abs(phi) > limit, T - barrier, T)
        return T

    def friction(self, v):
        """The wheels' friction forces (N, along e_k_perp) at lateral velocities v (m/s): the module doc's law."""
        return -self.grip * v / np.sqrt(v * v + self.slip_speed ** 2)

    def lateral(self, q, qdot):
        """(v, f): each wheel's lateral velocity (m/s) and friction force (N), along e_k_perp."""
        _, e_perp = unit_vectors(q[:self.n])
        v = constraint_matrix(self.lever, e_perp) @ qdot
        return v, self.friction(v)

    def kinetic_energy(self, q, qdot) -> float:
        """1/2 qdot^T M qdot (J), rotors included."""
        return 0.5 * float(qdot @ self.mass_matrix(q) @ qdot)

    def mass_matrix(self, q):
        _, e_perp = unit_vectors(q[:self.n])
        J = link_jacobians(self.lever, e_perp)
        return _inertia_from_jacobians(self.mass, self.inertia, J, (), np.float64) + self.rotor

    # ------------------------------------------------------------ dynamics
    def derivatives(self, y, command):
        """d/dt of y = (q (n+2), qdot (n+2), work (J), friction work (J)) under the held ``command``
        (n-1,) (N m): the work of every load but friction, and friction's (<= 0)."""
        n = self.n
        q, qdot = y[:n + 2], y[n + 2:2 * n + 4]
        e, e_perp = unit_vectors(q[:n])
        J = link_jacobians(self.lever, e_perp)
        M = _inertia_from_jacobians(self.mass, self.inertia, J, (), np.float64) + self.rotor
        B = _bias_from_geometry(self.mass, self.lever, e, J, qdot, n)
        Q = generalized_forces(self.model, q, qdot, self.joint_torques(command, q, qdot), e, J)
        A = constraint_matrix(self.lever, e_perp)
        v = A @ qdot
        f = self.friction(v)
        qddot = np.linalg.solve(M, Q - B + A.T @ f)
        return np.concatenate([qdot, qddot, [Q @ qdot, f @ v]])

    def jacobian(self, y, command, eps: float = 1e-7):
        """d(derivatives)/dy by central differences (the implicit integrator's Newton matrix)."""
        size = y.shape[0]
        out = np.empty((size, size))
        for i in range(size):
            step = eps * max(1.0, abs(y[i]))
            up, down = y.copy(), y.copy()
            up[i] += step
            down[i] -= step
            out[:, i] = (self.derivatives(up, command) - self.derivatives(down, command)) / (2.0 * step)
        return out

    def advance(self, y, command, dt: float, rtol: float = 1e-8, atol: float = 1e-10):
        """y after ``dt`` (s) with ``command`` held; y as :meth:`derivatives`. Raises RuntimeError if the
        integrator fails (never a silent, wrong state)."""
        from scipy.integrate import solve_ivp

        command = np.asarray(command, dtype=np.float64)
        result = solve_ivp(lambda t, z: self.derivatives(z, command), (0.0, dt), y, method="LSODA",
                           rtol=rtol, atol=atol, jac=lambda t, z: self.jacobian(z, command))
        if not result.success or not np.all(np.isfinite(result.y[:, -1])):
            raise RuntimeError(f"sliding-wheel model: the integrator failed ({result.message})")
        return result.y[:, -1]

    def advance_time_stepping(self, y, command, dt: float, substeps: int, impulse=None):
        """y after ``dt`` (s) with ``command`` held, by :mod:`.sliding_step`'s exact-Coulomb time stepping in
        ``substeps`` substeps (compiled; y as :meth:`derivatives`). Returns (y, sliding) with ``sliding`` (n,) the
        share of substeps each wheel slid. ``impulse`` (n,) (N s), if given, is the solver's warm start and gets
        the last substep's lateral impulses. Raises RuntimeError if the step fails (never a silent, wrong state)."""
        if not (isinstance(substeps, int) and substeps >= 1):
            raise ValueError(f"substeps must be an int >= 1, got {substeps!r}")
        n = self.n
        q = np.array(y[:n + 2], dtype=np.float64)
        qdot = np.array(y[n + 2:2 * n + 4], dtype=np.float64)
        impulse = np.zeros(n) if impulse is None else impulse
        stats = np.zeros(5)
        slid = np.zeros(n)
        start = (q.copy(), qdot.copy(), impulse.copy())
        ok = sliding_step.advance(q, qdot, np.asarray(command, dtype=np.float64), *self.compiled_constants(),
                                  dt / substeps, substeps, impulse, stats, slid, np.zeros(n),
                                  sliding_step.solve_method(self.rotor))
        if not ok:  # the fast solve did not settle: the step again with the Delassus solve
            q, qdot = start[0].copy(), start[1].copy()
            impulse[:] = start[2]
            stats[:], slid[:] = 0.0, 0.0
            ok = sliding_step.advance(q, qdot, np.asarray(command, dtype=np.float64), *self.compiled_constants(),
                                      dt / substeps, substeps, impulse, stats, slid, np.zeros(n), 2)
        if not ok or not (np.all(np.isfinite(q)) and np.all(np.isfinite(qdot))):
            raise RuntimeError("sliding-wheel model: the time step failed (a singular mass matrix or an "
                               "unconverged friction solve)")
        self.solver_stats = stats
        return np.concatenate([q, qdot, [y[-2] + stats[0], y[-1] + stats[1]]]), slid / substeps

    def compiled_constants(self) -> tuple:
        """The constants :func:`.sliding_step.advance` takes after (q, qdot, command), in its order."""
        if self._constants is None:
            G, g = sliding_step.inertia_constants(self.mass, self.lever)
            _, _, _, c_joint, c_wheel = self.model.parameters(np.float64)
            stall, no_load, t_max = self.motor
            limit, k_limit, c_limit = self.limit
            self._constants = (
                G, g, float(np.sum(self.mass)), np.ascontiguousarray(self.inertia), np.ascontiguousarray(self.lever),
                np.ascontiguousarray(self.grip), np.ascontiguousarray(c_joint, dtype=np.float64),
                np.ascontiguousarray(c_wheel, dtype=np.float64), stall, 0.0 if math.isinf(no_load) else 1.0 / no_load,
                t_max, 1.0 if self.back_emf_braking else 0.0, limit, k_limit, c_limit,
                compiled.inverse_room(limit) if limit > 0.0 else 0.0,
                np.ascontiguousarray(self.rotor), np.ascontiguousarray(self.mass, dtype=np.float64))
        return self._constants

    def initial(self, q, qdot):
        """y of a state (q, qdot), its work counters at 0."""
        return np.concatenate([np.asarray(q, dtype=np.float64), np.asarray(qdot, dtype=np.float64), [0.0, 0.0]])
