"""Compile step kernels into numba's on-disk cache in a process of its own, beside the first step's compile.

Started by :func:`snake_env.physics.stepping.compile_in_background` when an env is made and the kernels
are not cached yet. Numba compiles one function at a time per process; this second process takes, in
this order:

* two parts of the lane kernel the parent needs for its first step (:func:`compile_lane_parts`);
* with ``--unlimited-grip``, the wheel forces by their own sweep (``compiled.wheel_lateral_forces_batch``),
  which an env whose wheels never slip needs at its first step;
* the kernel only some steps need, :func:`~snake_env.physics.stepping._finish_rows` (refinement of the
  snakes that fail the step check, or their step undone).

With ``--sliding METHOD`` (the default wheels, :mod:`snake_env.physics.sliding_wheels`) it takes instead the
sliding wheels' row kernel of that friction solve (``sliding_step.ADVANCE_ROWS[METHOD]``, about half of a
first step's compile), says "done", releases the lock, and then compiles the rarely needed exact-solve kernel
too, under a lock of its own that it does not wait for.

The per-snake step, reset and observation of a snake beyond the lanes' angle range (1e5 rad, after
thousands of turns) compile in the parent if that ever happens.

One such process compiles at a time per cache (a lock file, :func:`lock_path`): the others, started by
other processes meanwhile (e.g. SubprocVecEnv workers), wait for it and then load what it cached.
The parent loads each from the cache when it first needs it (waiting for this process before the
first :func:`~snake_env.physics.stepping._finish_rows`). On POSIX this process says "done" on a pipe
(``--done-fd``) once every kernel is cached, so the parent does not wait for its exit as well (~0.4 s
of numba and LLVM teardown). Every model and settings tuple has the same
numba types (``compiled.kernel_model`` and ``stepping.step_settings`` fix them), so compiling for one
Snake5 serves every env.
"""

from __future__ import annotations

import hashlib
import os
import sys
import tempfile

import numpy as np
from numba import njit

from snake_env.dynamics import compiled, sliding_step
from snake_env.physics import stepping
from snake_env.physics.config import PhysicsConfig
from snake_env.physics.sliding_reference import sliding_wheels


@njit(error_model="numpy")  # not cached: it exists for its callee's compile, which numba caches
def _later_stages(model, s, nl, dt, inv_tol, v_ref):
    """Types the call of the RK4 stages after the first exactly as ``compiled.rk4_lanes_estimate`` makes
    it (``first`` the literal False), so that specialisation of ``rk4_stage_lanes`` gets compiled."""
    compiled.rk4_stage_lanes(model, s, nl, compiled._STAGE[2], False, dt, compiled._STAGE[0], inv_tol, v_ref)


def compile_lane_parts(model, n: int) -> None:
    """Two parts of the lane kernel the parent compiles at once: the traction pass
    (``compiled._traction_lanes``) and the RK4 stage after the first (one of the two specialisations of
    ``compiled.rk4_stage_lanes``), in the order the parent's compile asks for them, which then loads
    what this process has cached by then (its compile is ~40 % stages; a race: a part the parent asks
    for first it compiles itself)."""
    m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, stall, inv_w0, t_max, grip, rotor, braking = model
    s = np.zeros(compiled.lanes_scratch_size(n))
    compiled._traction_lanes(m, h, inertia, c_wheel, grip, rotor, s, np.uint64(1))
    _later_stages(model, s, 1, 0.01, 100.0, 0.1)


def compile_rare_kernels(model, settings, n: int, unlimited_grip: bool) -> None:
    """Compile (or load from the cache) the kernels named in the module doc by calling them on a batch of
    one snake with nothing left to finish (aux[AUX_REFINEMENTS] = 0), so they compute nothing."""
    q = np.zeros((1, n + 2))
    u = np.zeros((1, 2))
    torques = np.zeros((1, n - 1))
    obs = np.zeros((1, stepping.observation_size(n, False)))
    aux = np.zeros((1, stepping.AUX_SIZE))
    forces = np.zeros((1, n))
    scale = np.ones(1)
    if unlimited_grip:
        compiled.wheel_lateral_forces_batch(model, q, u, torques, forces, scale)
    stepping._finish_rows(model, settings, q, u, torques, obs, aux, forces, scale)


def compile_sliding_rows(method: int) -> None:
    """Compile (or load from the cache) the sliding wheels' row kernel of friction solve ``method`` by calling
    it on a batch of one snake with no row to step, so it computes nothing. Its argument types are every
    sliding model's (``SlidingWheels.compiled_constants``), so one Snake5 serves every env."""
    n = 5
    constants = sliding_wheels(PhysicsConfig(n_links=n, wheel_model="sliding")).compiled_constants()
    q, qdot = np.zeros((1, n + 2)), np.zeros((1, n + 2))
    impulse, slid, lateral = np.zeros((1, n)), np.zeros((1, n)), np.zeros((1, n))
    sliding_step.ADVANCE_ROWS[method](q, qdot, np.zeros((1, n - 1)), *constants, np.full(1, 1e-3),
                                      np.zeros(1, np.int64), np.zeros(0, np.int64), impulse, np.zeros((1, 5)), slid,
                                      lateral, np.zeros((1, 2)))


def lock_path() -> str:
    """The lock file of the cache this process compiles into: one per snake_env source tree and
    NUMBA_CACHE_DIR (numba's cache location follows from both)."""
    key = f"{os.path.abspath(stepping.__file__)}|{os.environ.get('NUMBA_CACHE_DIR', '')}"
    return os.path.join(tempfile.gettempdir(), f"snake_env_compile_{hashlib.sha1(key.encode()).hexdigest()[:16]}.lock")


def hold_the_lock(suffix: str = "", wait: bool = True):
    """Block until this process holds the compile lock (kept until it exits or closes it); the open file, or
    None where file locks are unavailable (then compiles may overlap, which is only slower). ``suffix``: a lock
    of its own for other kernels; ``wait=False``: None at once if another process holds it."""
    try:
        import fcntl
    except ImportError:  # not POSIX
        return None
    try:
        handle = open(lock_path() + suffix, "a")
    except OSError:
        return None
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
    except OSError:
        handle.close()
        return None
    return handle


def say_done() -> None:
    """Tell the parent (on its ``--done-fd`` pipe, if given) that the kernels it waits for are cached."""
    if "--done-fd" in sys.argv[1:]:  # the parent need not wait for this process's exit (~0.4 s)
        try:
            os.write(int(sys.argv[sys.argv.index("--done-fd") + 1]), b"d")
        except OSError:  # the parent has gone (or stopped listening): compile on for the next process
            pass


def main() -> None:
    lock = hold_the_lock()  # noqa: F841 (held until exit)
    if "--sliding" in sys.argv[1:]:
        method = int(sys.argv[sys.argv.index("--sliding") + 1])
        compile_sliding_rows(method)
        say_done()
        if lock is not None:  # the others waiting (e.g. SubprocVecEnv workers) load the row kernel now
            lock.close()
        # the exact solves' kernel (rotors, or where the fast solve did not settle; ~20 s), for later, by one
        # process at a time: another already at it caches it
        exact_lock = hold_the_lock(".exact", wait=False) if method == 0 else None
        if exact_lock is not None:
            compile_sliding_rows(2)
        return
    n = 5  # every n has the same numba types
    model = compiled.kernel_model(np.ones(n), np.full(n, 0.1), np.full(n, 1.0 / 300.0), np.zeros(n - 1),
                                  np.zeros(n), wheel_grip=np.full(n, 9.81), rotor_inertia=np.empty(0))
    settings = stepping.step_settings(0.01, 4, False, 1e-2, 1e-3, 1e-2, 6)
    compile_lane_parts(model, n)
    compile_rare_kernels(model, settings, n, "--unlimited-grip" in sys.argv[1:])
    say_done()


if __name__ == "__main__":
    main()
