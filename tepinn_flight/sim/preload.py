"""What the campaign's forkserver imports before it forks the workers: the simulation modules, the
multirotor controller's compiled code, the JSBSim step kernels and the quads' compiled flight loop,
loaded once there (numba's start-up, ≈ 0.5 s, is then paid once per campaign instead of once in every
worker)."""

from tepinn_flight.sim import campaign, jsbsim_native, quad_flight_kernel, simulate  # noqa: F401
from tepinn_flight.sim.multirotor import F450
from tepinn_flight.sim.quad_control_law import load_compiled

load_compiled(F450)
jsbsim_native.warm()
quad_flight_kernel.warm()
