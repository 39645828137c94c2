"""A campaign moved or renamed with its sensor TOML beside it resumes (session 53: the sensor file's absolute path in
the campaign's digest had refused the resume as "a different campaign"); the shipped campaigns' digests unchanged."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from tepinn_flight.sim.campaign import _manifest, expand, load_campaign, validate

CAMPAIGN = """name = "moved"
seed = 5
duration_s = 4.0
rate_hz = 400.0

[[groups]]
aircraft = ["F450"]
profiles = [{ name = "agile", maneuvers = ["flip", "roll"] }]
sensors = ["consumer", "mysensor.toml"]
repeats = 1
"""
SENSOR = """name = "mysensor"
[gyro]
arw_deg_sqrt_h = 0.3
range_deg_s = 500
"""


def _manifest_of(toml: Path) -> dict:
    cfg = load_campaign(toml)
    flights = expand(cfg, base=toml.parent)
    return _manifest(cfg, flights, validate(cfg, flights), base=toml.parent)


def test_a_campaign_moved_with_its_sensor_file_keeps_its_digest(tmp_path):
    a = tmp_path / "a"
    a.mkdir()
    (a / "c.toml").write_text(CAMPAIGN)
    (a / "mysensor.toml").write_text(SENSOR)
    m_a = _manifest_of(a / "c.toml")
    shutil.move(a, tmp_path / "b")
    m_b = _manifest_of(tmp_path / "b" / "c.toml")
    assert m_b["definition_sha256"] == m_a["definition_sha256"]  # the resume's test
    assert any(str(tmp_path / "b") in json.dumps(f) for f in m_b["flights"])  # the flights still load the file


def test_the_shipped_campaigns_keep_their_digest():
    root = Path(__file__).resolve().parents[1] / "flight_sims" / "campaigns"
    for name in ("mixed.toml", "heldout.toml"):
        m = _manifest_of(root / name)
        cfg = load_campaign(root / name)
        flights = expand(cfg, base=root)
        from tepinn_flight.sim.campaign import _digest

        definition = {"campaign": m["definition"], "sensors_resolved": validate(cfg, flights),
                      "flights": [[f.file, f.seed, f.sensor] for f in flights]}  # fmt: skip
        assert m["definition_sha256"] == _digest(definition)  # presets by name: as before
