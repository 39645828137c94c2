"""A multirotor flight's control updates and JSBSim steps in one compiled loop.

Where :mod:`tepinn_flight.sim.jsbsim_native` can call JSBSim's C++ (the executive's step, the property
reads and writes), :func:`fly_quad` runs what :func:`~tepinn_flight.sim.flight.fly`'s Python loop does
for a quad, update after update: the maneuver's law (:mod:`tepinn_flight.sim.quad_maneuver_law`), the
controller's laws on the state JSBSim holds (:func:`~tepinn_flight.sim.quad_control_law.control_update`),
the four motor commands written, and the JSBSim steps until the next update with their rows logged
(:func:`~tepinn_flight.sim.jsbsim_native.run_logged`). It returns to Python only where Python must act:
a maneuver that finished or needs the flight's random generator, the flight's end, or the height floor.
The same functions on the same numbers as the Python loop: the flights are the same bits
(``tests/test_quad_flight_kernel.py``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tepinn_flight.sim.jsbsim_native import CTX_GET, CTX_SUB, _call_double, _call_set, run_logged
from tepinn_flight.sim.quad_control_law import control_update
from tepinn_flight.sim.quad_maneuver_law import CONTINUE, maneuver_update

#: what :func:`fly_quad` returns besides the maneuver law's DONE and EVENT
FINISHED, STOPPED = 10, 11
#: the controller's context: the address of ``setDoubleValue``, then the pointers of the nodes the state is
#: read from (:data:`~tepinn_flight.sim.flight.STATE_PATHS`' order: Euler angles, body rates, height above
#: ground, NED velocity), then roll and pitch acceleration and the position north and east, then the four
#: motor commands' nodes
C_SET, C_STATE, N_STATE = 0, 1, 10
C_PD, C_QD, C_PN, C_PE = C_STATE + N_STATE, C_STATE + N_STATE + 1, C_STATE + N_STATE + 2, C_STATE + N_STATE + 3
C_CMD = C_STATE + N_STATE + 4
N_CTX = C_CMD + 4


@njit(cache=True)
def fly_quad(ctx, cctx, i0, n_sim, div, dt_sim, min_agl_ft, start_agl_m, skip_first, par, st, ref, obs, man, rows,
             state):  # fmt: skip
    """The control updates at JSBSim steps ``i0``, ``i0 + div``, … below ``n_sim``, each followed by its
    steps: ``(i, code)``. ``code``: the maneuver law's DONE or EVENT at the update of step ``i`` (the law
    ran; the controller did not), ``STOPPED`` at step ``i`` (the height floor, see
    :func:`~tepinn_flight.sim.jsbsim_native.run_logged`) or ``FINISHED``. ``skip_first``: the update at
    ``i0`` runs without the maneuver's law (Python ran it). ``ctx``, ``rows`` and ``state``: the
    :class:`~tepinn_flight.sim.jsbsim_native.Stepper`'s; ``cctx``: the controller's context (``C_*``);
    ``par``, ``st``, ``ref`` and ``obs``: the controller's parameters, integrators, reference and
    observation; ``man``: the maneuver's vector."""
    get_fn, sub, set_fn = ctx[CTX_GET], ctx[CTX_SUB], cctx[C_SET]
    have_state = False  # state holds what the step before this update logged
    skip = skip_first
    i = i0
    while i < n_sim:
        if not skip:
            code = maneuver_update(man, ref, obs, par, i * dt_sim)
            if code != CONTINUE:
                return i, code
        skip = False
        if not have_state:
            for j in range(N_STATE):
                state[j] = _call_double(get_fn, cctx[C_STATE + j])
        c0, c1, c2, c3 = control_update(
            par, st, ref, obs, start_agl_m, state[0], state[1], state[2], state[3], state[4], state[5],
            _call_double(get_fn, cctx[C_PD]), _call_double(get_fn, cctx[C_QD]), state[6], state[7], state[8],
            state[9], _call_double(get_fn, cctx[C_PN]), _call_double(get_fn, cctx[C_PE]))  # fmt: skip
        _call_set(set_fn, cctx[C_CMD], c0)
        _call_set(set_fn, cctx[C_CMD + 1], c1)
        _call_set(set_fn, cctx[C_CMD + 2], c2)
        _call_set(set_fn, cctx[C_CMD + 3], c3)
        n = min(div, n_sim - i)
        stop = run_logged(ctx, i, n, min_agl_ft, rows, state)
        if stop >= 0:
            return stop, STOPPED
        have_state = (i + n) % sub == 0
        i += div
    return i, FINISHED


def warm() -> None:
    """Load (or compile) the kernel once (the campaign's forkserver calls it). Called with nothing to do."""
    z = np.zeros(1)
    fly_quad(np.zeros(8, np.int64), np.zeros(N_CTX, np.int64), 0, 0, 1, 0.0025, 0.0, 0.0, False, z, z, z, z, z,
             np.empty((1, 1)), z)  # fmt: skip
