"""A stock JSBSim aircraft without the parts our simulation never uses: the same flights, faster.

JSBSim's F450 computes, every step, its own IMU, barometer and GPS sensor models (three
``<system>`` files, about 60 components with their noise), a rate SCAS whose output is summed
into the motor commands, and three ground-contact points. ``fly()`` models the sensors itself from
the truth, drives the motors with ``ScasEngage = 0`` (the SCAS's rate errors are multiplied by zero
and it adds exactly 0.0 to each external command) and stops a flight 2 m above the ground, where the
contacts (0.15 m below the centre of gravity) give zero force. The c172x runs JSBSim's own
autopilot (``c172ap`` and the ``Autopilot`` and ``GNCUtilities`` systems), disengaged: it adds
exactly 0.0 to the surfaces our controller commands; its six ground contacts never touch before a
flight stops 60 m up. Work whose result is thrown away or is the identity, yet about 40 % of each
``run()``.

:class:`LeanModel` names what to leave out; :func:`build_lean_aircraft` writes a copy of the
installed aircraft folder without it (into each flight's temporary folder, about a millisecond; the
ground contacts of all three vehicles emptied in their main file),
leaving the aerodynamics, mass, propulsion and effectors untouched. One kind of part must stay: a
component that draws noise from the generator the Dryden turbulence also uses (the c172x
autopilot's attitude sensor: leaving it out shifts every later turbulence draw), hence
``keep_only``; the F450's sensors have their own streams. Our own agile quad leaves out its four
ground contacts the same way (its model folder in ``flight_sims/aircraft`` is the one copied). The flights are bit-identical to the
stock models' (tests with severe turbulence, and down to the stop height; the 76-flight held-out and
120-flight training campaigns regenerated identical in session 21).
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
    #: elements of the main file to keep empty, each (opening tag, a text the element holds):
    #: ``("<ground_reactions>", "<contact")`` -> ``<ground_reactions/>`` (not an output's switch), or
    #: ``('<ground_reactions file="Gear.xml"/>', "Gear.xml")`` (the file then not read)
    empty: tuple[tuple[str, str], ...] = ()
    #: properties the rest of the model reads from what was dropped, declared at 0.0 (what the
    #: dropped, disengaged part gives them in our flights) where the first dropped element stood
    zero_properties: tuple[str, ...] = ()
    #: (file, its root element, elements kept (opening tags), properties declared): a file reduced to
    #: the parts that must stay — a sensor drawing its noise from the generator the turbulence uses
    keep_only: tuple[tuple[str, str, tuple[str, ...], tuple[str, ...]], ...] = ()
    #: a flight-control file to replace by the external commands' path alone, each
    #: (external command, ESC input) it then wires (None: the flight control as it is)
    fcs_file: str | None = None
    external_commands: tuple[tuple[str, str], ...] = ()


def external_fcs_xml(commands: tuple[tuple[str, str], ...], declare: tuple[str, ...] = ()) -> str:
    """A flight control that only passes each external command to its ESC input (a one-input
    summer: the value itself, as the stock mixer's ``0.0 + command``). ``declare``: further
    properties the stock file declared and the simulation writes (kept at 0.0 unless written)."""
    props = [f'  <property value="0.0">{p}</property>' for p in (*declare, *(c for c, _ in commands))]
    summers = [f"    <summer>\n      <input>{c}</input>\n      <output>{o}</output>\n    </summer>"
               for c, o in commands]
    return ('<?xml version="1.0"?>\n'
            "<!-- written by tepinn_flight.sim.lean_model: the stock flight control's external-command path "
            "alone -->\n"
            '<flight_control name="external commands only">\n' + "\n".join(props) + "\n"
            '  <channel name="External Input Summations">\n' + "\n".join(summers) + "\n  </channel>\n"
            "</flight_control>\n")  # fmt: skip


_FCS_DECLARED = ("fcs/ScasEngage",)  # the stock file's own property, written by the controller's set-up


def _element(text: str, tag: str, model: str, containing: str | None = None) -> tuple[int, int]:
    """(start, end) of the element opening with ``tag`` in ``text`` (its body too unless
    self-closing), among those whose text holds ``containing`` if given. ConfigError unless there
    is exactly one."""
    found = []
    at = text.find(tag)
    while at >= 0:
        end = at + len(tag)
        if not tag.endswith("/>"):
            name = re.match(r"<(\w+)", tag)
            close = text.find(f"</{name.group(1)}>", end) if name else -1
            if close < 0:
                raise ConfigError(f"JSBSim's {model}: {tag} is not closed")
            end = close + len(name.group(1)) + 3
        if containing is None or containing in text[at:end]:
            found.append((at, end))
        at = text.find(tag, at + 1)
    if len(found) != 1:
        what = tag if containing is None else f"{tag} with {containing}"
        raise ConfigError(f"JSBSim's {model} does not have {what} once ({len(found)} times)")
    return found[0]


def _drop(text: str, tag: str, model: str) -> tuple[str, int]:
    """``text`` without the element opening with ``tag`` (whole lines where it stands alone on
    them), and where it stood."""
    at, end = _element(text, tag, model)
    line = text.rfind("\n", 0, at) + 1
    if not text[line:at].strip():
        at = line
        nl = text.find("\n", end)
        if nl >= 0 and not text[end:nl].strip():
            end = nl + 1
    return text[:at] + text[end:], at


def _reduced(text: str, name: str, root: str, kept: tuple[str, ...], declared: tuple[str, ...], model: str) -> str:
    """A file of root element ``root`` holding ``declared`` properties and one channel of the ``kept``
    elements of ``text``, verbatim and in their order."""
    if not re.search(r"<" + re.escape(root) + r"[\s>]", text):
        raise ConfigError(f"JSBSim's {model} has no {name} with <{root}>")
    parts = sorted(_element(text, tag, model) for tag in kept)
    body = "".join(f"  <property> {p} </property>\n" for p in declared)
    body += '  <channel name="kept by tepinn_flight.sim.lean_model">\n'
    body += "".join(f"    {text[a:b]}\n" for a, b in parts) + "  </channel>\n"
    head = f'<?xml version="1.0"?>\n<!-- reduced by tepinn_flight.sim.lean_model -->\n<{root} name="{name} (reduced)">\n'
    return f"{head}{body}</{root}>\n"


def _read(path: Path) -> str:
    """A stock file's text ("" where it is missing: the checks then name it)."""
    return path.read_text() if path.is_file() else ""


def build_lean_aircraft(model: str, stock_root: Path, lean: LeanModel, dest_root: Path) -> Path:
    """Write ``dest_root/<model>/`` from ``stock_root/<model>/`` without ``lean``'s parts; return
    ``dest_root`` (the aircraft path for ``load_model_with_paths``). ConfigError where the stock
    files are not as expected (a different jsbsim version): the caller then flies the stock model."""
    src = Path(stock_root) / model
    main = src / f"{model}.xml"
    if not main.is_file() or (lean.fcs_file is not None and not (src / lean.fcs_file).is_file()):
        raise ConfigError(f"JSBSim's {model} has no {main.name} or {lean.fcs_file}")
    text = main.read_text()
    first = None
    for tag in lean.drop:
        text, at = _drop(text, tag, model)
        first = at if first is None else min(first, at)
    if lean.zero_properties:
        if first is None:
            raise ConfigError("zero_properties stand for the outputs of dropped parts: drop something")
        decl = "".join(f'\n    <property value="0.0">{p}</property>' for p in lean.zero_properties)
        system = f'  <system name="outputs of what tepinn_flight.sim.lean_model left out">{decl}\n  </system>\n'
        text = text[:first] + system + text[first:]
    for tag, holding in lean.empty:
        at, end = _element(text, tag, model, holding)
        text = text[:at] + "<" + re.match(r"<(\w+)", tag).group(1) + "/>" + text[end:]
    reduced = {name: _reduced(_read(src / name), name, root, kept, declared, model)
               for name, root, kept, declared in lean.keep_only}
    if lean.fcs_file is not None:
        fcs_stock = (src / lean.fcs_file).read_text()
        for cmd, esc in lean.external_commands:  # the stock path this replaces: cmd summed into esc
            if cmd not in fcs_stock or f"<output>{esc}</output>" not in fcs_stock:
                raise ConfigError(f"JSBSim's {model} flight control has no {cmd} -> {esc} path")
    dest = Path(dest_root) / model
    shutil.copytree(src, dest)
    (dest / main.name).write_text(text)
    if lean.fcs_file is not None:
        (dest / lean.fcs_file).write_text(external_fcs_xml(lean.external_commands, _FCS_DECLARED))
    for name, content in reduced.items():
        (dest / name).write_text(content)
    return Path(dest_root)
