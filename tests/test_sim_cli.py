"""``tepinn-flight simulate``: one flight, campaigns (parallel, resumable, deterministic), bad config."""

from __future__ import annotations

import json
import os
import subprocess
import sys

os.environ["MAVLINK20"] = "1"

import numpy as np
import pytest

from tepinn_flight.cli.main import main
from tests.consistency import rate_consistency
from tepinn_flight.record import read_record
from tepinn_flight.sim.campaign import MANIFEST, flight_seed

pytest.importorskip("jsbsim")


def sim(*args):
    return main(["simulate", *map(str, args)])


# --------------------------------------------------------------------------- bad configuration


@pytest.mark.parametrize(
    "args, message",
    [
        (["--aircraft", "nope"], "unknown aircraft 'nope'"),
        (["--aircraft", "F450", "--maneuvers", "flip,zoom"], "unknown maneuver 'zoom'"),
        (["--aircraft", "F450", "--duration", "-3"], "duration must be"),
        (["--aircraft", "F450", "--rate", "0"], "rate must be"),
        (["--aircraft", "F450", "--sensor", "nope"], "unknown sensor preset 'nope'"),
        (["--aircraft", "F450", "--sensor-set", "gyro.arw=1"], "unknown key 'gyro.arw'"),
        (["--aircraft", "F450", "--sensor-set", "gyro.arw_deg_sqrt_h=-1"], ">= 0"),
        (["--aircraft", "F450", "--turbulence", "storm"], "unknown turbulence 'storm'"),

        (["--campaign", "c.toml", "--tlog", "x.tlog"], "--tlog cannot be combined with --campaign"),
        (["--campaign", "c.toml", "--workers", "0"], "--workers must be >= 1"),
        (["--aircraft", "F450", "--workers", "2"], "--workers applies to --campaign only"),
    ],
)
def test_bad_configuration_is_one_line_and_exit_2(args, message, tmp_path, capsys):
    out = tmp_path / "x.parquet"
    assert sim(*args, "-o", out) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("tepinn-flight simulate: error:") and message in err
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_campaign_file_errors(tmp_path, capsys):
    c = tmp_path / "c.toml"
    cases = [
        ('name = "t"\nseed = 1\nsed = 2\n[[groups]]\naircraft = ["F450"]\n', "unknown key 'sed'"),
        ('name = "t"\nseed = 1\n[[groups]]\naircraft = ["F450"]\nrepeat = 2\n', "unknown key 'groups[0].repeat'"),
        ('name = "t"\nseed = 1\n[[groups]]\naircraft = ["B52"]\n', "unknown aircraft 'B52'"),
        ('name = "t"\nseed = 1\nduration_s = -1.0\n[[groups]]\naircraft = ["F450"]\n', "duration must be"),
        ('name = "t"\nseed = 1\n[[groups]]\naircraft = ["F450"]\nsensors = ["gold"]\n', "unknown sensor preset 'gold'"),
        ('name = "t"\nseed = 1\n[[groups]]\naircraft = ["F450"]\nprofiles = [{name = "a", maneuvers = ["loop"]}]\n',
         "unknown maneuver 'loop'"),
        ('name = "t"\nseed = 1\n[[groups]]\naircraft = ["F450"]\nrepeats = "two"\n', "must be an integer"),
        # (found per flight before, after the good ones had flown, with "re-run the same command" as advice)
        ('name = "t"\nseed = 1\nrate_hz = 200.0\n[[groups]]\naircraft = ["F450"]\nsensor_set = ["rate_hz=150"]\n',
         "sensor rate_hz 150 must divide the simulation rate 200 Hz"),
    ]
    for text, message in cases:
        c.write_text(text)
        assert sim("--campaign", c, "-o", tmp_path / "out") == 2, message
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
        assert not (tmp_path / "out").exists()


def test_subprocess_exit_code_and_single_line(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "TEPINN_DEBUG"}
    p = subprocess.run([sys.executable, "-m", "tepinn_flight", "simulate", "--aircraft", "nope", "-o",
                        str(tmp_path / "x.parquet")], capture_output=True, text=True, env=env, timeout=120)  # fmt: skip
    assert p.returncode == 2
    assert p.stderr.strip().splitlines() == ["tepinn-flight simulate: error: unknown aircraft 'nope' "
                                             "(known: c172x, F450, agile_quad)"]  # fmt: skip


# --------------------------------------------------------------------------- one flight


def test_single_flight_record_deterministic_and_consistent(tmp_path, capsys):
    a, b, c = tmp_path / "a.parquet", tmp_path / "b.parquet", tmp_path / "c.parquet"
    common = ["--aircraft", "F450", "--duration", "3", "--rate", "200", "--sensor", "tactical",
              "--sensor-set", "gyro.range_deg_s=2000"]  # fmt: skip
    assert sim(*common, "--seed", 3, "-o", a, "--tlog", tmp_path / "a.tlog") == 0
    assert sim(*common, "--seed", 3, "-o", b) == 0
    assert sim(*common, "--seed", 4, "-o", c) == 0
    assert "F450 3.0 s" in capsys.readouterr().out
    assert a.read_bytes() == b.read_bytes()
    assert a.read_bytes() != c.read_bytes()
    rec = read_record(a)
    m = rec.meta
    assert len(rec) == 600 and m["aircraft"] == "F450" and m["seed"] == 3 and m["termination"] == "completed"
    assert m["sensor_preset"] == "tactical" and m["sensor"]["gyro"]["range_deg_s"] == 2000.0
    assert m["sensor_overrides"] == ["gyro.range_deg_s=2000"] and m["maneuvers"]
    assert m["source_kind"] == "jsbsim" and m["reference_source"] == "jsbsim-truth"
    np.testing.assert_allclose(np.linalg.norm(rec.q_ref_wxyz, axis=1), 1.0, atol=1e-12)
    # independent check of the whole chain: gyro against rates differentiated from the true attitude
    rc = rate_consistency(rec)
    assert np.all(rc.corr[rc.moving] > 0.99)
    np.testing.assert_allclose(rc.gain[rc.moving], 1.0, atol=0.03)
    # tactical bias is tiny against the motion
    assert np.abs(rec.data["gyr_bias_x_rad_s"]).max() < 1e-4
    # the tlog comes back through our own ingest
    pytest.importorskip("tepinn_flight.ingest.tlog")
    from tepinn_flight.ingest import ingest_log

    back = ingest_log(tmp_path / "a.tlog")
    np.testing.assert_allclose(back.gyr_rad_s, rec.gyr_rad_s, atol=1e-6)
    np.testing.assert_allclose(back.t_s, rec.t_s, atol=1e-6)


# --------------------------------------------------------------------------- campaigns


CAMPAIGN = """
name = "tiny"
seed = 5
duration_s = 1.5
rate_hz = 200.0
[[groups]]
aircraft = ["F450"]
profiles = [{ name = "flips", maneuvers = ["flip"] }]
sensors = ["consumer", "industrial"]
turbulence = ["none"]
repeats = 2
"""


def test_campaign_seed_replaced_from_the_command_line(tmp_path, capsys):
    """`simulate --campaign C --seed N` flies C's flights with N as the campaign's seed: the same bytes as a copy of
    the file with `seed = N` (the README's other-seed checks were such copies, kept outside the repository), other
    flights than C's own seed; a folder flown with another seed is refused; a negative seed is one line, exit 2."""
    one = CAMPAIGN.replace('sensors = ["consumer", "industrial"]', 'sensors = ["consumer"]').replace("repeats = 2", "repeats = 1")
    cfile, copy = tmp_path / "tiny.toml", tmp_path / "tiny7.toml"
    cfile.write_text(one)
    copy.write_text(one.replace("seed = 5", "seed = 7"))
    assert sim("--campaign", cfile, "-o", tmp_path / "s7", "--seed", 7, "--workers", 1, "-q") == 0
    assert sim("--campaign", copy, "-o", tmp_path / "c7", "--workers", 1, "-q") == 0
    assert sim("--campaign", cfile, "-o", tmp_path / "s5", "--workers", 1, "-q") == 0
    (f,) = [p.name for p in (tmp_path / "s7").glob("*.parquet")]
    assert (tmp_path / "s7" / f).read_bytes() == (tmp_path / "c7" / f).read_bytes()
    assert read_record(tmp_path / "s7" / f).meta["seed"] == flight_seed(7, 0) != read_record(tmp_path / "s5" / f).meta["seed"]
    assert json.loads((tmp_path / "s7" / MANIFEST).read_text())["seed"] == 7
    capsys.readouterr()
    assert sim("--campaign", cfile, "-o", tmp_path / "s5", "--seed", 7, "-q") == 2
    assert "holds a different campaign" in capsys.readouterr().err
    assert sim("--campaign", cfile, "-o", tmp_path / "neg", "--seed", -1, "-q") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'seed' must be >= 0" in err and not (tmp_path / "neg").exists()


def test_campaign_parallel_resumable_deterministic(tmp_path, capsys):
    cfile = tmp_path / "tiny.toml"
    cfile.write_text(CAMPAIGN)
    out2, out1 = tmp_path / "w2", tmp_path / "w1"
    assert sim("--campaign", cfile, "-o", out2, "--workers", 2, "-q") == 0
    files = sorted(p.name for p in out2.glob("*.parquet"))
    assert files == [f"{i:04d}-F450-flips-{s}-none-r{r}.parquet"
                     for i, (s, r) in enumerate([("consumer", 0), ("consumer", 1), ("industrial", 0), ("industrial", 1)])]
    manifest = json.loads((out2 / MANIFEST).read_text())
    seeds = [f["seed"] for f in manifest["flights"]]
    ref = [int(s.generate_state(1, np.uint32)[0]) for s in np.random.SeedSequence(5).spawn(4)]
    assert seeds == ref == [flight_seed(5, i) for i in range(4)]
    recs = [read_record(out2 / f) for f in files]
    assert [r.meta["seed"] for r in recs] == seeds
    assert recs[2].meta["sensor_preset"] == "industrial"
    assert not np.array_equal(recs[0].gyr_rad_s, recs[1].gyr_rad_s)

    # same bytes with one worker (seeds by index, not by worker or order)
    assert sim("--campaign", cfile, "-o", out1, "--workers", 1, "-q") == 0
    for f in files:
        assert (out1 / f).read_bytes() == (out2 / f).read_bytes()

    # resume: delete one record, re-run: only that one is recomputed
    before = {f: (out2 / f).stat().st_mtime_ns for f in files}
    data = (out2 / files[1]).read_bytes()
    (out2 / files[1]).unlink()
    (out2 / ".0003-x.parquet.abc.tmp").write_bytes(b"junk")  # a killed run's temporary
    capsys.readouterr()
    assert sim("--campaign", cfile, "-o", out2, "--workers", 2) == 0
    assert "4 flights, 1 computed, 3 already done, 0 failed" in capsys.readouterr().out
    assert (out2 / files[1]).read_bytes() == data
    for f in files:
        if f != files[1]:
            assert (out2 / f).stat().st_mtime_ns == before[f]
    assert not list(out2.glob(".*.tmp"))

    # resume: a record cut short and one emptied (a copy cut off, a crash before the disk had the data) are flown
    # again, with a note, and come back bit for bit (review60: both had been counted done for good)
    (out2 / files[0]).write_bytes((out1 / files[0]).read_bytes()[:1000])
    (out2 / files[2]).write_bytes(b"")
    capsys.readouterr()
    assert sim("--campaign", cfile, "-o", out2, "--workers", 1) == 0
    said = capsys.readouterr()
    assert "4 flights, 2 computed, 2 already done, 0 failed" in said.out
    assert "2 record(s) in" in said.err and "cannot be read (cut or damaged): flown again" in said.err
    for f in files:
        assert (out2 / f).read_bytes() == (out1 / f).read_bytes()

    # a folder flown before the sensors' lost samples and stamp jitter existed (session 29; its manifest's digest
    # made without those keys) holds the very flights where they stay 0: resumed, not refused
    import hashlib

    def digest(m, strip=()):
        sensors = {k: {f: v for f, v in s.items() if f not in strip} for k, s in m["sensors_resolved"].items()}
        d = {"campaign": m["definition"], "sensors_resolved": sensors,
             "flights": [[f["file"], f["seed"], f["sensor"]] for f in m["flights"]]}  # fmt: skip
        return hashlib.sha256(json.dumps(d, sort_keys=True, default=str).encode()).hexdigest()

    manifest = json.loads((out2 / MANIFEST).read_text())
    assert digest(manifest) == manifest["definition_sha256"]
    older = digest(manifest, strip=("lost_fraction", "stamp_jitter_s"))
    assert older != manifest["definition_sha256"]
    (out2 / MANIFEST).write_text(json.dumps({**manifest, "definition_sha256": older}))
    capsys.readouterr()
    assert sim("--campaign", cfile, "-o", out2, "--workers", 1) == 0
    assert "4 flights, 0 computed, 4 already done, 0 failed" in capsys.readouterr().out
    # ... but not where the campaign now loses samples: other flights
    cfile.write_text(CAMPAIGN.replace('turbulence = ["none"]', 'turbulence = ["none"]\nsensor_set = ["lost_fraction=0.02"]'))
    (out2 / MANIFEST).write_text(json.dumps({**manifest, "definition_sha256": older}))
    assert sim("--campaign", cfile, "-o", out2, "-q") == 2
    assert "holds a different campaign" in capsys.readouterr().err

    # a different campaign definition is refused in the same folder
    cfile.write_text(CAMPAIGN.replace("seed = 5", "seed = 6"))
    assert sim("--campaign", cfile, "-o", out2, "-q") == 2
    assert "holds a different campaign" in capsys.readouterr().err


def test_flights_failing_for_one_cause_say_it_once(tmp_path, capsys, monkeypatch):
    # e.g. JSBSim's aircraft data missing: every flight fails the same way — one line for the cause,
    # not one per flight, and the error names it with its count
    import tepinn_flight.sim.simulate as simulate

    def broken(*a, **k):
        raise OSError("Can't find the default root directory")

    monkeypatch.setattr(simulate, "simulate_record", broken)
    cfile = tmp_path / "tiny.toml"
    cfile.write_text(CAMPAIGN)
    assert sim("--campaign", cfile, "-o", tmp_path / "out", "--workers", 1, "-q") == 1
    err = capsys.readouterr().err
    assert err.count("Can't find the default root directory") == 2, err  # the first flight's line, the summary
    assert "4 flight(s) failed: OSError: Can't find the default root directory (4 flights)" in err
    assert not list((tmp_path / "out").glob("*.parquet"))


def test_a_sensor_rate_that_cannot_be_reached_is_refused_before_the_flight(tmp_path, capsys, monkeypatch):
    """The single flight checks the sensor's rate against the simulation's before flying (review60: after the whole
    flight had flown); the campaign already did."""
    import tepinn_flight.sim.simulate as S

    def flown(*a, **k):
        raise AssertionError("the flight was flown before the sensor rate was checked")

    monkeypatch.setattr(S, "simulate_record", flown)
    assert sim("--aircraft", "F450", "--rate", 500, "--sensor-set", "rate_hz=200", "-o", tmp_path / "x.parquet") == 2
    assert "sensor rate_hz 200 must divide the simulation rate 500 Hz" in capsys.readouterr().err


def test_an_install_without_the_simulation_data_says_what_it_lacks(tmp_path, capsys, monkeypatch):
    """A non-editable install has no flight_sims folder beside the package: `simulate` says so and what to do (review60:
    "unknown sensor preset 'consumer-raw' (known: none found in .../site-packages/flight_sims/sensors)")."""
    monkeypatch.setenv("TEPINN_FLIGHT_SIMS", str(tmp_path / "site-packages" / "flight_sims"))
    assert sim("--aircraft", "F450", "--duration", 1, "-o", tmp_path / "x.parquet") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no flight_sims folder at" in err and "pip install -e ." in err, err
