"""The lean F450 (JSBSim's own sensor models, disengaged SCAS and ground contacts left out), the lean
c172x (its disengaged autopilot but for one noisy sensor, its ground contacts) and our agile quad
without its contacts: the same flights as the full models, bit for bit, and the parts really gone; a
jsbsim whose files differ gets the stock model."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

jsbsim = pytest.importorskip("jsbsim")

from tepinn_flight.errors import ConfigError  # noqa: E402
from tepinn_flight.sim import fixed_wing, multirotor  # noqa: E402
from tepinn_flight.sim.flight import fly  # noqa: E402
from tepinn_flight.sim.jsbsim_env import FT_TO_M, getter, jsbsim_root, open_fdm, setter  # noqa: E402
from tepinn_flight.sim.lean_model import LeanModel, build_lean_aircraft  # noqa: E402

ARRAYS = ("t_s", "q_nb_wxyz", "gyr_true_rad_s", "acc_true_m_s2", "pos_ned_m", "vel_ned_m_s")
STOCK_ROOT = jsbsim_root() / "aircraft"


def same_flights(monkeypatch, module, params: str, aircraft: str, seconds: float, seed: int, turbulence: str):
    """Fly ``aircraft`` with its lean model, then with ``module.params`` made full, and check that
    every array and the maneuvers are equal → (lean flight, full flight)."""
    lean = fly(aircraft, seconds, 400.0, seed=seed, turbulence=turbulence)
    monkeypatch.setattr(module, params, dataclasses.replace(getattr(module, params), lean=None))
    full = fly(aircraft, seconds, 400.0, seed=seed, turbulence=turbulence)
    for name in ARRAYS:
        assert np.array_equal(getattr(lean, name), getattr(full, name)), name
    assert lean.maneuvers == full.maneuvers and len(lean.t_s) == round(seconds * 400)
    return lean, full


@pytest.mark.parametrize("seed, turbulence", [(3, "moderate"), (11, "severe")])
def test_lean_f450_flies_the_stock_models_flights_bit_for_bit(monkeypatch, seed, turbulence):
    lean, stock = same_flights(monkeypatch, multirotor, "F450", "F450", 6.0, seed, turbulence)
    assert lean.meta["jsbsim_model"] == "F450 (lean)" and stock.meta["jsbsim_model"] == "F450"
    assert np.ptp(lean.gyr_true_rad_s[:, 0]) > 1.0  # a flight that moves, not a hover at rest


def test_lean_agile_quad_flies_its_full_models_flights_bit_for_bit(monkeypatch):
    """Our own quad without its ground contacts: the same flights, and the same fall to the stop height."""
    spec = multirotor.AGILE_QUAD.lean
    lean, full = same_flights(monkeypatch, multirotor, "AGILE_QUAD", "agile_quad", 8.0, 5, "severe")
    assert lean.meta["jsbsim_model"] == "agile_quad (own) (lean)" and full.meta["jsbsim_model"] == "agile_quad (own)"
    stop_m = multirotor.QuadVehicle(multirotor.AGILE_QUAD).min_agl_m
    runs = {}
    for s in (spec, None):
        with open_fdm("agile_quad", 1 / 400, own_aircraft=True, lean=s) as fdm:
            assert fdm["gear/num-units"] == (0 if s else 4)
            fdm["ic/h-agl-ft"] = (stop_m + 1.0) / FT_TO_M
            fdm["ic/theta-deg"] = 30.0
            fdm.run_ic()
            for i in range(4):
                fdm[f"fcs/motor-cmd[{i}]"] = 0.2  # it sinks, pitched
            rows = []
            while not rows or rows[-1][0] * FT_TO_M > stop_m:
                fdm.run()
                rows.append([fdm["position/h-agl-ft"], fdm["attitude/theta-rad"], fdm["forces/fbz-total-lbs"]])
                assert len(rows) < 4000
            runs[s is None] = np.array(rows)
    assert np.array_equal(runs[True], runs[False]) and len(runs[True]) > 50


def test_lean_c172x_flies_the_stock_models_flights_bit_for_bit(monkeypatch):
    """Its autopilot's attitude sensor draws noise from the turbulence's generator: kept, the
    turbulence is the same; a flight through loops and pull-ups in severe turbulence."""
    spec = fixed_wing.C172X.lean
    lean, stock = same_flights(monkeypatch, fixed_wing, "C172X", "c172x", 25.0, 7, "severe")
    assert lean.meta["jsbsim_model"] == "c172x (lean)" and stock.meta["jsbsim_model"] == "c172x"
    assert len(lean.maneuvers) >= 3
    with open_fdm("c172x", 1 / 400, lean=spec) as fdm:
        pm = fdm.get_property_manager()
        assert fdm["gear/num-units"] == 0
        assert pm.get_node("ap/roll-cmd-norm-output") is not None and fdm["ap/roll-cmd-norm-output"] == 0.0
        assert pm.get_node("ap/heading_hold") is None  # the rest of the autopilot is gone
        assert pm.get_node("fcs/attitude/sensor/phi-rad") is not None  # its noisy sensor stays


def test_lean_model_leaves_the_sensor_models_out_and_passes_the_commands_through():
    spec = multirotor.F450.lean
    info = {}
    with open_fdm("F450", 1 / 400, lean=spec, info=info) as fdm:
        assert info["jsbsim_model"] == "F450 (lean)"
        pm = fdm.get_property_manager()
        assert pm.get_node("sensor/imu/gyroZ_rps") is None and pm.get_node("sensor/gps/lat_rad") is None
        assert pm.get_node("fcs/cmdRoll_rps") is None  # the SCAS is gone
        assert fdm["gear/num-units"] == 0  # and the ground contacts
        fdm["ic/h-agl-ft"] = 300.0
        fdm.run_ic()
        cmds = [0.61, 0.37, 0.52, 0.44]
        for (cmd, esc), c in zip(spec.external_commands, cmds):
            setter(fdm, cmd)(c)
        fdm.run()
        assert [getter(fdm, esc)() for _, esc in spec.external_commands] == cmds
    with open_fdm("F450", 1 / 400, info=info) as fdm:  # the stock model has them
        assert info["jsbsim_model"] == "F450"
        assert fdm.get_property_manager().get_node("sensor/imu/gyroZ_rps") is not None
        assert fdm["gear/num-units"] == 3


def test_unexpected_stock_files_fall_back_to_the_stock_model(tmp_path):
    bad = dataclasses.replace(multirotor.F450.lean, drop=('<system file="SensorImu.xml"/>', '<system file="NoSuchSystem.xml"/>'))
    with pytest.raises(ConfigError, match="NoSuchSystem.xml"):
        build_lean_aircraft("F450", STOCK_ROOT, bad, tmp_path / "a")
    wrong_path = dataclasses.replace(multirotor.F450.lean, external_commands=(("fcs/cmdXX_ext_nd", "fcs/cmdEscXX_nd"),))
    with pytest.raises(ConfigError, match="cmdXX_ext_nd"):
        build_lean_aircraft("F450", STOCK_ROOT, wrong_path, tmp_path / "b")
    no_gear = dataclasses.replace(multirotor.F450.lean, empty=(('<ground_reactions file="Gear.xml"/>', "Legs.xml"),))
    with pytest.raises(ConfigError, match="with Legs.xml once"):
        build_lean_aircraft("F450", STOCK_ROOT, no_gear, tmp_path / "d")
    with pytest.raises(ConfigError, match="no c172x.xml or"):
        build_lean_aircraft("c172x", STOCK_ROOT, LeanModel(fcs_file="NoFcs.xml"), tmp_path / "c")
    info = {}
    with open_fdm("F450", 1 / 400, lean=bad, info=info) as fdm:
        assert info["jsbsim_model"] == "F450"
        assert fdm.get_property_manager().get_node("sensor/imu/gyroZ_rps") is not None


def test_lean_f450_falls_like_the_stock_one_down_to_the_stop_height():
    """No ground contacts in the lean model: the same fall down to where fly() stops a flight."""
    stop_m = multirotor.QuadVehicle(multirotor.F450).min_agl_m
    paths = ("position/h-agl-ft", "attitude/phi-rad", "velocities/v-down-fps", "forces/fbz-total-lbs",
             "velocities/qi-rad_sec")
    runs = {}
    for lean in (multirotor.F450.lean, None):
        with open_fdm("F450", 1 / 400, lean=lean) as fdm:
            fdm["ic/h-agl-ft"] = (stop_m + 1.5) / FT_TO_M
            fdm["ic/phi-deg"] = 20.0
            fdm.run_ic()
            fdm.get_propulsion().init_running(-1)
            fdm["fcs/ScasEngage"] = 0.0
            for cmd, _ in multirotor.F450.lean.external_commands:
                fdm[cmd] = 0.35  # too little thrust: it sinks, tilted
            rows = []
            while not rows or rows[-1][0] * FT_TO_M > stop_m:
                fdm.run()
                rows.append([fdm[p] for p in paths])
                assert len(rows) < 4000
            runs[lean is None] = np.array(rows)
    assert runs[True].shape == runs[False].shape and len(runs[True]) > 100
    assert np.array_equal(runs[True], runs[False])
    assert runs[True][-1, 0] * FT_TO_M <= stop_m < runs[True][-2, 0] * FT_TO_M


def test_build_drops_whole_elements_and_keeps_the_rest(tmp_path):
    """On a toy aircraft folder: a self-closing element and one with a body go, line and all;
    everything else is copied as it was; an emptied element stays, with no body and no file."""
    src = tmp_path / "stock" / "toy"
    src.mkdir(parents=True)
    main = ('<?xml version="1.0"?>\n<fdm_config name="toy">\n  <metrics file="M.xml"/>\n'
            '  <system file="Noisy.xml"/>\n  <system file="Autopilot">\n    <property value="0.5"> a/b </property>\n'
            '  </system>\n  <system file="Kept.xml"/>\n  <ground_reactions file="G.xml"/>\n</fdm_config>\n')
    (src / "toy.xml").write_text(main)
    (src / "G.xml").write_text("<?xml version='1.0'?>\n<ground_reactions>\n  <contact/>\n</ground_reactions>\n")
    (src / "M.xml").write_text("<metrics/>\n")
    spec = LeanModel(drop=('<system file="Noisy.xml"/>', '<system file="Autopilot">'),
                     empty=(('<ground_reactions file="G.xml"/>', "G.xml"),))  # fmt: skip
    root = build_lean_aircraft("toy", tmp_path / "stock", spec, tmp_path / "lean")
    out = (root / "toy" / "toy.xml").read_text()
    assert out == ('<?xml version="1.0"?>\n<fdm_config name="toy">\n  <metrics file="M.xml"/>\n'
                   '  <system file="Kept.xml"/>\n  <ground_reactions/>\n</fdm_config>\n')
    assert (root / "toy" / "M.xml").read_text() == "<metrics/>\n"
    assert (root / "toy" / "G.xml").read_text() == (src / "G.xml").read_text()  # copied, no longer read
    assert (src / "toy.xml").read_text() == main  # the stock folder untouched
    with pytest.raises(ConfigError, match="not closed"):
        build_lean_aircraft("toy", tmp_path / "stock", LeanModel(drop=('<ground_reactions file="G.xml"',)), tmp_path / "x")


def test_build_zero_properties_kept_elements_and_emptied_inline_elements(tmp_path):
    src = tmp_path / "stock" / "toy"
    src.mkdir(parents=True)
    (src / "toy.xml").write_text(
        '<fdm_config name="toy">\n  <ground_reactions>\n    <contact name="a"/>\n  </ground_reactions>\n'
        '  <system file="Autopilot">\n    <property> x </property>\n  </system>\n  <autopilot file="ap"/>\n'
        '  <output><ground_reactions> OFF </ground_reactions></output>\n</fdm_config>\n')
    (src / "ap.xml").write_text('<?xml version="1.0"?>\n<autopilot name="AP">\n  <channel name="c">\n'
                                '    <sensor name="s1">\n      <noise> 0.1 </noise>\n    </sensor>\n'
                                '    <pid name="p"/>\n    <switch name="w">\n    </switch>\n  </channel>\n</autopilot>\n')
    spec = LeanModel(drop=('<system file="Autopilot">',), zero_properties=("ap/out",),
                     keep_only=(("ap.xml", "autopilot", ('<switch name="w">', '<sensor name="s1">'), ("ap/in",)),),
                     empty=(("<ground_reactions>", "<contact"),))  # fmt: skip
    root = build_lean_aircraft("toy", tmp_path / "stock", spec, tmp_path / "lean")
    main = (root / "toy" / "toy.xml").read_text()
    assert main == ('<fdm_config name="toy">\n  <ground_reactions/>\n'
                    '  <system name="outputs of what tepinn_flight.sim.lean_model left out">\n'
                    '    <property value="0.0">ap/out</property>\n  </system>\n  <autopilot file="ap"/>\n'
                    '  <output><ground_reactions> OFF </ground_reactions></output>\n</fdm_config>\n')
    ap = (root / "toy" / "ap.xml").read_text()
    assert "<pid" not in ap and ap.index('<sensor name="s1">') < ap.index('<switch name="w">')  # stock order
    assert "<property> ap/in </property>" in ap and "<noise> 0.1 </noise>" in ap and ap.rstrip().endswith("</autopilot>")
    with pytest.raises(ConfigError, match="zero_properties"):
        build_lean_aircraft("toy", tmp_path / "stock", LeanModel(zero_properties=("a",)), tmp_path / "x")
    with pytest.raises(ConfigError, match="once"):  # two <ground_reactions> and none chosen
        build_lean_aircraft("toy", tmp_path / "stock", LeanModel(empty=(("<ground_reactions>", "ground"),)), tmp_path / "y")
