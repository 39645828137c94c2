"""JSBSim set-up in the order that works, silencing, and cached property access.

The pitfalls handled here are the reproduced ones in ``/work/shared/notes/jsbsim.md``:
``set_dt`` before ``load_model`` (P1), output files redirected to a private temporary folder and
disabled (P8), every log message silenced with a C++ logger (P5; a C++ logger has no GIL issue, P6),
and the rotational-position integrator switched to Buss' second-order method so the logged attitude
is consistent with the logged body rates (see :func:`open_fdm`).
"""

from __future__ import annotations

import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterator

from tepinn_flight.errors import ConfigError
from tepinn_flight.sim import FLIGHT_SIMS_DIR

if TYPE_CHECKING:
    from tepinn_flight.sim.lean_model import LeanModel

#: Our own aircraft definitions (``flight_sims/aircraft/<name>/<name>.xml``).
AIRCRAFT_DIR = FLIGHT_SIMS_DIR / "aircraft"

FT_TO_M = 0.3048
LBF_TO_N = 4.4482216152605
SLUG_TO_KG = 14.59390293720636

#: JSBSim integrator codes (FGPropagate::eIntegrateType).
INTEGRATOR_BUSS2 = 7


def jsbsim_module():
    """Import jsbsim lazily so that reading records never needs it."""
    try:
        import jsbsim
    except ImportError as exc:  # pragma: no cover - jsbsim is a dependency
        raise ConfigError(f"the simulator needs the jsbsim package ({exc})") from exc
    return jsbsim


def jsbsim_root() -> Path:
    """The folder of JSBSim's own aircraft, engines and systems: the package's folder where it holds
    them (the wheels ship them there). ``jsbsim.get_default_root_dir()`` looks only in the
    interpreter's site-packages, so a jsbsim installed elsewhere (``pip install --target``, a
    ``PYTHONPATH`` folder) could not find them; it is the fallback."""
    jsbsim = jsbsim_module()
    here = Path(jsbsim.__file__).resolve().parent
    if (here / "aircraft").is_dir() and (here / "engine").is_dir():
        return here
    try:
        return Path(jsbsim.get_default_root_dir())
    except OSError as exc:
        raise ConfigError(f"JSBSim's aircraft data were not found beside the jsbsim package ({here}): {exc}") from exc


def jsbsim_version() -> str:
    return str(jsbsim_module().__version__)


def silence() -> None:
    """Silence JSBSim in this thread (its logger is thread-local).

    A C++ ``DefaultLogger`` at FATAL level drops every message (P5) and, unlike a Python
    ``FGLogger`` subclass, cannot abort the process when several threads use JSBSim (P6).
    """
    jsbsim = jsbsim_module()
    if hasattr(jsbsim, "set_logger"):  # jsbsim >= 1.3; older versions only honour set_debug_level
        jsbsim.set_logger(jsbsim.DefaultLogger(jsbsim.LogLevel.FATAL))


@contextmanager
def open_fdm(model: str, dt_s: float, own_aircraft: bool = False,
             lean: LeanModel | None = None, info: dict | None = None) -> Iterator[object]:
    """Yield a loaded, silent ``FGFDMExec`` stepping at ``dt_s``; clean up its output folder.

    ``own_aircraft`` loads ``flight_sims/aircraft/<model>`` with the package's engines and
    systems; otherwise the aircraft that ships with JSBSim; either without ``lean``'s parts where
    given (:mod:`tepinn_flight.sim.lean_model`: the same flights; the model as it is where its files
    are not as expected). ``info``, where given, gets ``"jsbsim_model"``: what was loaded ("<model>",
    "<model> (lean)", "<model> (own)" or "<model> (own) (lean)").
    """
    jsbsim = jsbsim_module()
    silence()
    out_dir = tempfile.mkdtemp(prefix="tepinn-jsbsim-")
    try:
        root = jsbsim_root()
        fdm = jsbsim.FGFDMExec(str(root))
        fdm.set_debug_level(0)
        fdm.set_output_path(out_dir)  # P8: <output> files go here, never to the working folder
        fdm.set_dt(dt_s)  # P1: before load_model
        stock_dir = AIRCRAFT_DIR if own_aircraft else None
        aircraft_dir, variant = stock_dir, f"{model} (own)" if own_aircraft else model
        if lean is not None:
            from tepinn_flight.sim.lean_model import build_lean_aircraft

            try:  # a copy in this flight's own folder (a few ms), removed with it
                aircraft_dir = build_lean_aircraft(model, stock_dir or root / "aircraft", lean,
                                                   Path(out_dir) / "aircraft")  # fmt: skip
                variant = f"{variant} (lean)"
            except (ConfigError, OSError):
                pass  # these files differ (or the copy failed): the model as it is
        if aircraft_dir is not None:
            ok = fdm.load_model_with_paths(
                model, str(aircraft_dir), str(root / "engine"), str(root / "systems")
            )
        else:
            ok = fdm.load_model(model)
        if not ok:
            raise ConfigError(f"JSBSim could not load aircraft {model!r}")
        fdm.disable_output()
        # Attitude integrated with Buss' augmented 2nd-order method: the quaternion advances with
        # the mid-step rate w_k + dt/2 * wdot_k, i.e. exactly what linear interpolation of the
        # logged rates between samples implies (the JSBSim default, rectangular Euler, lags
        # by half a step: 0.75 deg of attitude error per 600 deg/s of rate change).
        fdm["simulation/integrator/position/rotational"] = INTEGRATOR_BUSS2
        if info is not None:
            info["jsbsim_model"] = variant
        yield fdm
    finally:
        shutil.rmtree(out_dir, ignore_errors=True)


def getter(fdm, path: str) -> Callable[[], float]:
    """Cached fast read of a property (about 50 ns against 70 ns for ``fdm[path]``)."""
    node = fdm.get_property_manager().get_node(path)
    if node is None:
        raise ConfigError(f"JSBSim property {path!r} does not exist")
    return node.get_double_value


def setter(fdm, path: str, create: bool = False) -> Callable[[float], None]:
    """Cached fast write of a property."""
    node = fdm.get_property_manager().get_node(path, create)
    if node is None:
        raise ConfigError(f"JSBSim property {path!r} does not exist")
    return node.set_double_value
