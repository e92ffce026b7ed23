"""The physical settings of a snake env as one typed config (dm_control's Physics half).

:class:`PhysicsConfig` is the single place where the physical kwargs are named,
given units and defaults, and validated: its field names are the env kwargs
and the YAML ``env_kwargs`` keys, for every task, in the single and the vector
env alike. Adding a setting is one field line here (plus, if the kernel needs
it, one argument where :meth:`PhysicsConfig.build` fills
:class:`~snake_env.physics.stepping.PhysicsParams`).

Validation is driven by each field's ``metadata`` (:func:`setting`): a bad
value raises ``ValueError`` with one line naming the argument, the allowed
values and the unit.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from snake_env.dynamics import SnakeModel
from snake_env.dynamics.model import GRAVITY  # m/s^2: the wheels' normal load m_k g, the cost of transport
from snake_env.dynamics.validation import check_n_links

from .actuators import ACTUATORS
from .actuators import resolve as resolve_actuator
from .actuator_response import latency_substeps
from .randomization import resolve as resolve_randomize
from .settings import check_fields, setting
from .stepping import PhysicsParams

class _DefaultSimDt(float):
    """The default sim_dt's type: a float that tells PhysicsConfig it was not given, so that it may be
    divided into substeps where RK4 needs them (a sim_dt passed explicitly, even 0.01, is honoured
    or refused)."""


# Defaults (units in the field docs). One env step = sim_dt * frame_skip = 0.04 s, like Swimmer-v5.
DEFAULT_SIM_DT = _DefaultSimDt(0.01)  # s, one RK4 step
DEFAULT_FRAME_SKIP = 4  # RK4 steps per env step
DEFAULT_MAX_TORQUE = 1.0  # N m, the paper's Table III torque amplitude
DEFAULT_JOINT_DAMPING = 0.01  # N m s/rad, viscous joint friction
DEFAULT_WHEEL_DAMPING = 0.1  # N s/m per wheel, rolling resistance
DEFAULT_JOINT_LIMIT = math.pi / 2  # rad, limit on |phi_k|
DEFAULT_LIMIT_STIFFNESS = 20.0  # N m/rad, least stiffness of the barrier beyond the limit
DEFAULT_LIMIT_DAMPING = 0.2  # N m s/rad, damper beyond the limit (at the least stiffness)
# With the joint's effective inertia I_eff ~ 0.015 kg m^2 (n = 5, paper links) the limit
# rings at sqrt(k / I_eff) ~ 36 rad/s (omega dt = 0.36 per RK4 step) with damping ratio
# ~0.2. A larger damper switches on a larger force jump c * phidot at the limit, which
# RK4 resolves poorly at sim_dt = 0.01 s (measured energy-balance error grows ~15x at c = 1).
# The barrier's stiffness k = max(joint_limit_stiffness, LIMIT_STIFFNESS_PER_TORQUE * max_torque)
# (N m/rad): at k d = max_torque the joint is pushed 0.1 rad past the limit, and the
# barrier's potential diverges before the fold, so it wins against any torque. Its damper
# is scaled by sqrt(k / joint_limit_stiffness) so the damping ratio stays that of the kwargs.
LIMIT_STIFFNESS_PER_TORQUE = 10.0  # 1/rad
MAX_JOINT_LIMIT = math.radians(150.0)  # rad: leaves >= 20 deg of barrier before the fold (170 deg)
INTEGRATORS = ("rk4_refined", "rk4")
WHEEL_MODELS = ("no_slip", "sliding")  # physics.batch picks the batch physics of each
DEFAULT_INTEGRATOR = "rk4_refined"
DEFAULT_ENERGY_TOLERANCE = 1e-2  # relative work-energy residual per env step
DEFAULT_ERROR_TOLERANCE = 1e-2  # RK4 embedded local-error estimate per substep, relative (see physics)
DEFAULT_MAX_REFINEMENTS = 6  # substep halvings: down to sim_dt / 64
ENERGY_FLOOR_PER_TORQUE = 1e-3  # J per N m: the residual test's energy floor is this * max_torque * 1 rad
MAX_REFINEMENTS_LIMIT = 12
# RK4's stability interval is about 2.79 on the negative real axis and 2.83 on the
# imaginary axis; sim_dt must keep the stiffest rate of the setting inside it with margin.
RK4_STABLE_RATE_STEP = 2.5
# The robot of the newest ids (forward v3): servo-class joint motors and rubber wheels on a floor.
DEFAULT_ACTUATOR = "servo"  # physics.actuators: 1 N m stall torque, 3.14 rad/s no-load speed (XH430-W350)
# mu of a rubber wheel on a dry concrete floor: the kinetic coefficient 0.8 (static 1.0) of Serway & Beichner,
# Physics for Scientists and Engineers, 5th ed., Table 5.2; the Engineering ToolBox gives 0.6-0.85. The
# kinetic value, because beyond the cone the wheel slides.
DEFAULT_WHEEL_FRICTION = 0.8
# A wheel slides when its lateral force exceeds its grip by more than this share of the grip. The traction
# limit holds the wheels it saturates at mu m_k g up to rounding (at most 4.4e-16 of the grip above it,
# measured under bang-bang torques on Snake5 and Snake12), while the motion's own excess starts at ~3e-3
# of the grip (the smallest seen there): 1e-9 separates the two and counts no held wheel as sliding.
SLIP_TOLERANCE = 1e-9


class _DefaultWheelModel(str):
    """The default wheel_model's type while PhysicsConfig checks its fields: a str that tells it the model was
    not given, so that unlimited grip (wheel_friction=None) may make it "no_slip" (an explicit "sliding" with
    unlimited grip is refused). The stored value is a plain str."""


# The wheels of the newest ids (forward v4): each grips within mu m_k g and slides under Coulomb friction beyond it.
DEFAULT_WHEEL_MODEL = _DefaultWheelModel("sliding")
# The physics of the earlier versions of every id, pinned in their registrations (snake_env.registration),
# newest first: PHYSICS_HISTORY[k] is the version k + 1 before the newest.
# - forward and path v3, command and reach v2: the servo motors of v4 with braking capped at their current
#   limit, and the paper's no-slip wheels under the traction limit;
# - forward and path v2, command and reach v1: ideal torque sources and wheels that grip without limit (the
#   paper's no-slip constraint at any force). Unlimited grip makes wheel_model "no_slip" and an ideal source has
#   no braking to cap (back_emf_braking False), so actuator="ideal", wheel_friction=None alone give v2 on any
#   later id bit for bit; the registration pins all four, so that v2 with a finite mu keeps v2's no-slip wheels.
TRACTION_LIMIT_PHYSICS = {"wheel_model": "no_slip", "back_emf_braking": False}
IDEAL_PHYSICS = {"actuator": "ideal", "wheel_friction": None, **TRACTION_LIMIT_PHYSICS}
PHYSICS_HISTORY = (TRACTION_LIMIT_PHYSICS, IDEAL_PHYSICS)


@dataclass(frozen=True)
class PhysicsConfig:
    """Physical and integration settings shared by every task (kwargs = YAML keys).

    `paper_model=True` is the paper's model (section II): no dissipation, no
    joint limits, ideal torque sources and wheels that grip without limit; it
    sets joint_damping = wheel_damping = 0, joint_limit = None,
    actuator = "ideal" and wheel_friction = None, and rejects other values for them.
    """

    n_links: int = setting(5, "links", "int", minimum=1, doc="number of links n >= 2")
    frame_skip: int = setting(DEFAULT_FRAME_SKIP, "RK4 steps per env step", "int", minimum=0,
                              doc="RK4 steps per env step")
    sim_dt: float = setting(DEFAULT_SIM_DT, "s", minimum=0.0, doc="RK4 step; env dt = sim_dt * frame_skip")
    max_torque: float = setting(DEFAULT_MAX_TORQUE, "N m", minimum=0.0, doc="joint torque at action 1")
    joint_damping: float = setting(DEFAULT_JOINT_DAMPING, "N m s/rad", minimum=0.0, strict=False,
                                   doc="viscous joint damping")
    wheel_damping: float = setting(DEFAULT_WHEEL_DAMPING, "N s/m", minimum=0.0, strict=False,
                                   doc="rolling resistance per wheel")
    joint_limit: float | None = setting(DEFAULT_JOINT_LIMIT, "rad, 150 deg at most: the barrier needs room before "
                                        "links fold at 170 deg", "optional_real", minimum=0.0,
                                        maximum=MAX_JOINT_LIMIT, doc="limit on |phi_k|; None disables")
    joint_limit_stiffness: float = setting(DEFAULT_LIMIT_STIFFNESS, "N m/rad", minimum=0.0, strict=False,
                                           doc="least barrier stiffness beyond the limit; raised to 10 * max_torque")
    joint_limit_damping: float = setting(DEFAULT_LIMIT_DAMPING, "N m s/rad", minimum=0.0, strict=False,
                                         doc="barrier damper at that least stiffness")
    paper_model: bool = setting(False, "-", "bool", doc="the paper's model: no damping, no limits")
    mass: float = setting(1.0, "kg", "per_link", doc="per-link mass (paper Table II)")
    length: float = setting(0.2, "m", "per_link", doc="per-link length (paper Table II)")
    inertia: float = setting(0.005, "kg m^2", "per_link", doc="per-link central inertia (paper Table II)")
    exclude_current_positions_from_observation: bool = setting(True, "-", "bool",
                                                               doc="leave the CM x, y out of the observation")
    integrator: str = setting(DEFAULT_INTEGRATOR, "-", "choice", maximum=INTEGRATORS,
                              doc='"rk4_refined": checked RK4, failing steps refined; "rk4": checked fixed-step RK4')
    energy_tolerance: float = setting(DEFAULT_ENERGY_TOLERANCE, "relative work-energy residual", minimum=0.0,
                                      maximum=1.0, doc="largest relative work-energy residual of an env step")
    error_tolerance: float = setting(DEFAULT_ERROR_TOLERANCE, "relative local error per RK4 substep", minimum=0.0,
                                     maximum=1.0, doc="tolerance of RK4's embedded local-error estimate per substep")
    max_refinements: int = setting(DEFAULT_MAX_REFINEMENTS, "substep halvings", "int", minimum=0, strict=False,
                                   maximum=MAX_REFINEMENTS_LIMIT, doc="substep halvings of a failing step")
    wheel_friction: float | None = setting(DEFAULT_WHEEL_FRICTION, "-", "optional_real", minimum=0.0,
                                           doc="wheel-floor friction coefficient mu: each wheel holds mu m_k g "
                                               "sideways (see wheel_model); None: unlimited grip, the paper's "
                                               "no-slip wheels (wheel_model is then 'no_slip')")
    wheel_model: str = setting(DEFAULT_WHEEL_MODEL, "-", "choice", maximum=WHEEL_MODELS,
                               doc='"sliding": each wheel grips within mu m_k g and slides under Coulomb friction '
                                   'beyond it (physics.sliding_wheels); "no_slip": the paper\'s wheels (eq. 27), the '
                                   'motors\' torques scaled so no wheel needs more than mu m_k g (traction limit), '
                                   'info wheel_slip flags the motion\'s excess')
    actuator: str = setting(DEFAULT_ACTUATOR, "-", "choice", maximum=ACTUATORS,
                            doc='joint motors: "ideal" torque sources, or a DC-motor preset (physics.actuators)')
    stall_torque: float | None = setting(None, "N m", "optional_real", minimum=0.0,
                                         doc="motor torque at rest (None: the actuator preset's)")
    no_load_speed: float | None = setting(None, "rad/s", "optional_real", minimum=0.0,
                                          doc="joint rate at which the driving torque falls to 0 (None: the preset's)")
    torque_limit: float | None = setting(None, "N m", "optional_real", minimum=0.0,
                                         doc="current limit as a joint torque (None: the preset's)")
    back_emf_braking: bool = setting(True, "-", "bool",
                                     doc="a motor back-driven past omega_0 (1 + torque_limit / stall_torque) brakes "
                                         "with its back-EMF's torque, which its driver cannot cap; False: braking "
                                         "capped at torque_limit (v3 and before; dynamics.motor)")
    rotor_inertia: float = setting(0.0, "kg m^2", minimum=0.0, strict=False,
                                   doc="each joint motor's reflected rotor inertia N^2 J_r (gear ratio N; MuJoCo's "
                                       "joint armature): the spinning rotor's kinetic energy 1/2 N^2 J_r phidot^2 is "
                                       "in the dynamics and the energy check; 0: massless rotors (every preset)")
    torque_lag: float = setting(0.0, "s", minimum=0.0, strict=False,
                                doc="time constant of the first-order lag from command to motor torque (the current "
                                    "loop; MuJoCo's dyntype 'filter'); 0: instant (physics.actuator_response)")
    control_latency: float = setting(0.0, "s", minimum=0.0, strict=False,
                                     doc="delay of each command before it reaches the motor: whole sim_dt substeps, "
                                         "at most one env step; 0: none (physics.actuator_response)")
    randomize: bool | dict | None = setting(None, "-", "mapping",
                                            doc="per-episode domain randomization: None (off), True (default "
                                                "ranges) or {name: [low, high]} (physics.randomization)")

    def __post_init__(self):
        # sim_dt left at its default may be divided into substeps where RK4 needs them (build); an
        # explicit sim_dt is honoured or refused
        object.__setattr__(self, "_auto_substeps", isinstance(self.sim_dt, _DefaultSimDt))
        object.__setattr__(self, "n_links", check_n_links(self.n_links))
        check_fields(self)
        if self._auto_substeps:  # keep the marker through check_fields and dataclasses.replace
            object.__setattr__(self, "sim_dt", DEFAULT_SIM_DT)
        if self.paper_model:
            # Only the defaults may be overridden silently; anything else contradicts the flag.
            conflicts = [name for name, default in (("joint_damping", DEFAULT_JOINT_DAMPING),
                                                    ("wheel_damping", DEFAULT_WHEEL_DAMPING))
                         if getattr(self, name) not in (default, 0.0)]
            if self.joint_limit not in (None, DEFAULT_JOINT_LIMIT):
                conflicts.append("joint_limit")
            if self.actuator not in ("ideal", DEFAULT_ACTUATOR) or any(
                    getattr(self, name) is not None for name in ("stall_torque", "no_load_speed", "torque_limit")):
                conflicts.append("actuator")
            if self.wheel_friction not in (None, DEFAULT_WHEEL_FRICTION):
                conflicts.append("wheel_friction")
            conflicts += [name for name in ("torque_lag", "control_latency", "rotor_inertia")
                          if getattr(self, name) != 0.0]
            if self.randomize not in (None, False):
                conflicts.append("randomize")
            if conflicts:
                raise ValueError(f"paper_model=True fixes joint_damping=0, wheel_damping=0, joint_limit=None, "
                                 f"actuator='ideal', wheel_friction=None, torque_lag=0, control_latency=0, "
                                 f"rotor_inertia=0 and randomize=None; do not also pass {', '.join(conflicts)}")
            for name, value in (("joint_damping", 0.0), ("wheel_damping", 0.0), ("joint_limit", None),
                                ("actuator", "ideal"), ("wheel_friction", None)):
                object.__setattr__(self, name, value)
        if self.wheel_friction is None:  # unlimited grip: sliding wheels never slide, the no-slip model itself
            if self.wheel_model == "sliding" and not isinstance(self.wheel_model, _DefaultWheelModel):
                raise ValueError("wheel_model='sliding' needs wheel_friction, a mu > 0 (None: unlimited grip, the "
                                 "no-slip model itself)")
            object.__setattr__(self, "wheel_model", "no_slip")
        object.__setattr__(self, "wheel_model", str(self.wheel_model))
        if self.actuator == "ideal":  # a torque source has no current limit to brake past
            object.__setattr__(self, "back_emf_braking", False)
        latency_substeps(self.control_latency, self.sim_dt, self.frame_skip)  # one-line ValueError if not whole
        object.__setattr__(self, "_motor", resolve_actuator(self.actuator, self.stall_torque, self.no_load_speed,
                                                            self.torque_limit))
        object.__setattr__(self, "_randomize", resolve_randomize(
            self.randomize, motor=self._motor is not None, grip=self.wheel_friction is not None,
            rotor=self.rotor_inertia > 0, sim_dt=float(self.sim_dt), frame_skip=self.frame_skip))

    @property
    def dt(self) -> float:
        """Duration of one env step (s)."""
        return self.sim_dt * self.frame_skip

    @property
    def randomized(self) -> dict[str, tuple[float, float]]:
        """The ranges drawn from at every reset ({} without randomization), see physics.randomization."""
        return self._randomize

    @property
    def responds_instantly(self) -> bool:
        """Whether a command reaches the joints at once (no torque lag, no latency): the one-call step."""
        return self.torque_lag == 0.0 and self.control_latency == 0.0

    @property
    def versions_back(self) -> int:
        """How many physics versions before the newest these motors and wheels are (:data:`PHYSICS_HISTORY`;
        0: the newest's, or settings of no version), which picks the gaits searched on that version's ids."""
        for back in range(len(PHYSICS_HISTORY), 0, -1):  # the oldest first: its pins include the later ones'
            if all(getattr(self, name) == value for name, value in PHYSICS_HISTORY[back - 1].items()):
                return back
        return 0

    def wheel_load(self) -> np.ndarray:
        """m_k g (N) of every wheel (n,): its normal load on flat ground."""
        return np.broadcast_to(np.asarray(self.mass, np.float64), (self.n_links,)) * GRAVITY

    def grip(self) -> np.ndarray:
        """mu m_k g (N) of every wheel (n,), the largest lateral force it holds; inf without ``wheel_friction``."""
        return (math.inf if self.wheel_friction is None else self.wheel_friction) * self.wheel_load()

    def build(self) -> tuple[SnakeModel, PhysicsParams]:
        """The dynamics model and the compiled step's constants of these settings.

        Where the setting's stiffest rate (see :func:`stiffest_rates`) puts sim_dt above RK4's
        stability limit, a default sim_dt is divided into the fewest stable substeps
        (``PhysicsParams.substeps``) and an explicit one is refused."""
        model = SnakeModel(n_links=self.n_links, mass=self.mass, length=self.length, inertia=self.inertia,
                           joint_damping=self.joint_damping, wheel_damping=self.wheel_damping)
        m, h, inertia, c_joint, c_wheel = model.parameters(np.float64)
        limit_stiffness, limit_damping = limit_barrier(self.joint_limit_stiffness, self.joint_limit_damping,
                                                       self.max_torque)
        refined = self.integrator == "rk4_refined"
        params = PhysicsParams(
            mass=m, half_length=h, inertia=inertia, joint_damping=c_joint, wheel_damping=c_wheel,
            joint_limit=0.0 if self.joint_limit is None else self.joint_limit,  # the kernel reads <= 0 as "no limit"
            limit_stiffness=limit_stiffness, limit_damping=limit_damping,
            sim_dt=self.sim_dt, frame_skip=self.frame_skip,
            include_position=not self.exclude_current_positions_from_observation,
            energy_tolerance=self.energy_tolerance, energy_floor=ENERGY_FLOOR_PER_TORQUE * self.max_torque,
            # "rk4": a plain fixed step, no error control (the guards still apply)
            error_tolerance=self.error_tolerance if refined else math.inf,
            max_refinements=self.max_refinements if refined else 0,
            wheel_grip=None if self.wheel_friction is None else self.grip(),
            # massless rotors leave the kernels' rotor terms out altogether (the previous physics bit for bit)
            rotor_inertia=np.full(self.n_links - 1, float(self.rotor_inertia)) if self.rotor_inertia > 0 else None,
            back_emf_braking=self.back_emf_braking,
            **({} if self._motor is None else dict(
                stall_torque=self._motor.stall_torque, torque_limit=self._motor.torque_limit,
                inverse_no_load_speed=1.0 / self._motor.no_load_speed if self._motor.no_load_speed > 0 else 0.0)))
        bound, rate_name = max_stable_sim_dt(params, self.max_torque)
        if self.sim_dt > bound:
            if not self._auto_substeps:
                raise ValueError(f"sim_dt must be in (0, {bound:.3g}] s for these settings (the {rate_name} rate "
                                 f"{RK4_STABLE_RATE_STEP / bound:.3g} 1/s needs rate * sim_dt <= "
                                 f"{RK4_STABLE_RATE_STEP} for a stable RK4 step), got {self.sim_dt!r}; leave sim_dt "
                                 f"at its default to have it divided into substeps")
            # the fewest equal substeps that RK4 steps stably; the env step dt is unchanged
            params = dataclasses.replace(params, substeps=math.ceil(self.sim_dt / bound))
        return model, params


def limit_barrier(joint_limit_stiffness, joint_limit_damping, max_torque):
    """(stiffness (N m/rad), damping (N m s/rad)) of the joint-limit barrier for these kwargs."""
    stiffness = max(joint_limit_stiffness, LIMIT_STIFFNESS_PER_TORQUE * max_torque)
    damping = joint_limit_damping
    if joint_limit_stiffness > 0.0:
        damping *= math.sqrt(stiffness / joint_limit_stiffness)
    return stiffness, damping


def stiffest_rates(params: PhysicsParams, max_torque: float) -> dict[str, float]:
    """The setting's fastest linear rates (1/s) at rest, which a stable RK4 step must resolve.

    A joint's effective inertia is at least half the smaller central inertia of its two
    links, I_j (kg m^2): a bound, approached only when the links' masses are small against
    I / h^2 (Snake2 with inertia m L^2 / 12 turns like 2.25^2 I_j, tests/benchmarks/test_fuzz.py,
    so the rates below err on the stiff side); against it act the joint and
    limit dampers (rate c / I_j), the limit spring (sqrt(k / I_j)) and the torque
    (sqrt(max_torque / (I_j * 1 rad)): the rate at which a joint from rest turns a
    radian); the wheel dampers act on the link masses (c / m); a motor's back-EMF slope
    tau_s / omega_0 (N m s/rad) is a joint damper too. A motor's reflected rotor inertia adds to I_j.
    """
    inertia_j = float(np.min(params.inertia)) / 2.0
    if params.rotor_inertia is not None:  # a rotor turns with its joint: its inertia adds to the joint's
        inertia_j += float(np.min(params.rotor_inertia))
    joint_damping = float(np.max(params.joint_damping, initial=0.0))
    rates = {
        "joint damping": joint_damping / inertia_j,
        "wheel damping": float(np.max(params.wheel_damping)) / float(np.min(params.mass)),
        "torque": math.sqrt(max_torque / inertia_j),
    }
    if params.torque_limit < math.inf:  # the motor's back-EMF slope acts as a joint damper tau_s / omega_0
        rates["motor back-EMF"] = (params.stall_torque * params.inverse_no_load_speed + joint_damping) / inertia_j
    if params.joint_limit > 0.0:
        rates["joint-limit damping"] = (params.limit_damping + joint_damping) / inertia_j
        rates["joint-limit stiffness"] = math.sqrt(params.limit_stiffness / inertia_j)
    return rates


def max_stable_sim_dt(params: PhysicsParams, max_torque: float) -> tuple[float, str]:
    """(largest accepted sim_dt (s), the rate that bounds it) for a setting."""
    rates = stiffest_rates(params, max_torque)
    name = max(rates, key=rates.get)
    return (RK4_STABLE_RATE_STEP / rates[name] if rates[name] > 0.0 else math.inf), name


def sliding(lateral_force, grip) -> np.ndarray:
    """Whether each wheel slides: |lateral force| above its grip by more than :data:`SLIP_TOLERANCE` of it
    (a wheel the traction limit holds at its grip, up to rounding, grips). Any matching shapes (N)."""
    return np.abs(lateral_force) > grip * (1.0 + SLIP_TOLERANCE)


@njit(cache=True, nogil=True)
def sliding_into(lateral_force, grip, out) -> None:
    """:func:`sliding` of (B, n) forces and grips (N), written into ``out`` (B, n) bool: the same comparison,
    compiled (the env step's hot path; numpy's three ufuncs on the single env's (1, n) row cost ~2 us of its
    ~20 us step)."""
    limit = 1.0 + SLIP_TOLERANCE
    for b in range(lateral_force.shape[0]):
        for k in range(lateral_force.shape[1]):
            out[b, k] = abs(lateral_force[b, k]) > grip[b, k] * limit
