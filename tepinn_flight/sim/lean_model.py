"""A stock JSBSim aircraft without the parts our simulation never uses: the same flights, faster.

JSBSim's F450 computes, every step, its own IMU, barometer and GPS sensor models (three
``<system>`` files, about 60 components with their noise), a rate SCAS whose output is summed
into the motor commands, and three ground-contact points. ``fly()`` models the sensors itself from
the truth, drives the motors with ``ScasEngage = 0`` (the SCAS's rate errors are multiplied by zero
and it adds exactly 0.0 to each external command) and stops a flight 2 m above the ground, where the
contacts (0.15 m below the centre of gravity) give zero force — work whose result is thrown away or
is the identity, yet about 40 % of each ``run()``. :class:`LeanModel` names what to leave out;
:func:`build_lean_aircraft` writes a copy of the installed aircraft folder with those ``<system>``
files removed, the flight control replaced by the external commands' path alone (each
``fcs/cmd*_ext_nd`` into its ESC input) and the named files emptied, leaving the aerodynamics,
mass, propulsion and effectors files untouched. The flights are bit-identical to the stock model's
(each sensor has its own random stream, so the Dryden turbulence draws the same numbers; tested
with turbulence on, and down to the stop height). Not leaned: the c172x, whose disengaged
autopilot (c172ap, its Autopilot and GNCUtilities systems: 30 % of its ``run()``) adds exactly 0.0
to the surfaces but draws its attitude sensor's noise from the generator the turbulence uses, so
leaving it out changes every flight with turbulence (measured in session 21).
"""

from __future__ import annotations

import re
import shutil
from dataclasses import dataclass
from pathlib import Path

from tepinn_flight.errors import ConfigError


@dataclass(frozen=True)
class LeanModel:
    """What to leave out of a stock JSBSim aircraft (``aircraft/<model>/`` of the jsbsim package)."""

    #: elements of the model's main file to remove, each named by its opening tag as written there:
    #: ``'<system file="SensorImu.xml"/>'``, or ``'<system file="Autopilot">'`` with its body
    drop: tuple[str, ...] = ()
    #: a flight-control file to replace by the external commands' path alone, each
    #: (external command, ESC input) it then wires (None: the flight control as it is)
    fcs_file: str | None = None
    external_commands: tuple[tuple[str, str], ...] = ()
    #: (file, its root element) to leave empty: ground contacts of a vehicle that never touches down
    empty_files: tuple[tuple[str, str], ...] = ()


def external_fcs_xml(commands: tuple[tuple[str, str], ...], declare: tuple[str, ...] = ()) -> str:
    """A flight control that only passes each external command to its ESC input (a one-input
    summer: the value itself, as the stock mixer's ``0.0 + command``). ``declare``: further
    properties the stock file declared and the simulation writes (kept at 0.0 unless written)."""
    props = [f'  <property value="0.0">{p}</property>' for p in (*declare, *(c for c, _ in commands))]
    summers = [f"    <summer>\n      <input>{c}</input>\n      <output>{o}</output>\n    </summer>" for c, o in commands]
    return ('<?xml version="1.0"?>\n'
            "<!-- written by tepinn_flight.sim.lean_model: the stock flight control's external-command path "
            "alone -->\n"
            '<flight_control name="external commands only">\n' + "\n".join(props) + "\n"
            '  <channel name="External Input Summations">\n' + "\n".join(summers) + "\n  </channel>\n"
            "</flight_control>\n")  # fmt: skip


_FCS_DECLARED = ("fcs/ScasEngage",)  # the stock file's own property, written by the controller's set-up


def _drop(text: str, tag: str, model: str) -> str:
    """``text`` without the element opening with ``tag`` (its body too unless self-closing).
    ConfigError unless it is there exactly once."""
    at = text.find(tag)
    if at < 0 or text.find(tag, at + 1) >= 0:
        raise ConfigError(f"JSBSim's {model} does not have {tag} once")
    end = at + len(tag)
    if not tag.endswith("/>"):
        name = re.match(r"<(\w+)", tag)
        close = text.find(f"</{name.group(1)}>", end) if name else -1
        if close < 0:
            raise ConfigError(f"JSBSim's {model}: {tag} is not closed")
        end = close + len(name.group(1)) + 3
    line = text.rfind("\n", 0, at) + 1  # whole lines where the element is alone on them
    if not text[line:at].strip():
        at = line
        nl = text.find("\n", end)
        if nl >= 0 and not text[end:nl].strip():
            end = nl + 1
    return text[:at] + text[end:]


def build_lean_aircraft(model: str, stock_root: Path, lean: LeanModel, dest_root: Path) -> Path:
    """Write ``dest_root/<model>/`` from ``stock_root/<model>/`` without ``lean``'s parts; return
    ``dest_root`` (the aircraft path for ``load_model_with_paths``). ConfigError where the stock
    files are not as expected (a different jsbsim version): the caller then flies the stock model."""
    src = Path(stock_root) / model
    main = src / f"{model}.xml"
    if not main.is_file() or (lean.fcs_file is not None and not (src / lean.fcs_file).is_file()):
        raise ConfigError(f"JSBSim's {model} has no {main.name} or {lean.fcs_file}")
    text = main.read_text()
    for tag in lean.drop:
        text = _drop(text, tag, model)
    if lean.fcs_file is not None:
        fcs_stock = (src / lean.fcs_file).read_text()
        for cmd, esc in lean.external_commands:  # the stock path this replaces: cmd summed into esc
            if cmd not in fcs_stock or f"<output>{esc}</output>" not in fcs_stock:
                raise ConfigError(f"JSBSim's {model} flight control has no {cmd} -> {esc} path")
    for name, root in lean.empty_files:
        if not re.search(r"<" + re.escape(root) + r"[\s>]", (src / name).read_text() if (src / name).is_file() else ""):
            raise ConfigError(f"JSBSim's {model} has no {name} with <{root}>")
    dest = Path(dest_root) / model
    shutil.copytree(src, dest)
    (dest / main.name).write_text(text)
    if lean.fcs_file is not None:
        (dest / lean.fcs_file).write_text(external_fcs_xml(lean.external_commands, _FCS_DECLARED))
    for name, root in lean.empty_files:
        (dest / name).write_text(f'<?xml version="1.0"?>\n<!-- emptied by tepinn_flight.sim.lean_model -->\n<{root}/>\n')
    return Path(dest_root)
