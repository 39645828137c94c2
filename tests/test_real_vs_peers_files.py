"""``benchmarks/real_vs_peers.py`` on files a user names (session 46): which files it scores, under which label and
group, and which it lists apart with the reason ``evaluate`` would keep them out of its summary for. No estimator
runs here: these are the script's choices, checked on the shared logs whose defects are known (``SOURCES.md``)."""

from __future__ import annotations

import importlib.util
import tomllib
from pathlib import Path

from tests.conftest import broad_trial, real_log

REPO = Path(__file__).resolve().parents[1]


def _rvp():
    spec = importlib.util.spec_from_file_location("real_vs_peers", REPO / "benchmarks/real_vs_peers.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_motion_class_names_broads_classes_without_number_disturbance_or_variant():
    mc = _rvp().motion_class
    assert mc("01_undisturbed_slow_rotation_A") == "slow rotation"
    assert mc("18_undisturbed_fast_translation_with_breaks_B") == "fast translation with breaks"
    assert mc("broad_25_disturbed_tapping_B") == "tapping"
    assert mc("32_disturbed_attached_magnet_1cm") == "attached magnet"
    assert mc("39_something_new") == "something new"  # a class this code has never seen keeps its words


def test_a_telemetry_rate_imu_a_log_without_imu_and_a_failed_reference_are_listed_apart_with_their_reason():
    rvp = _rvp()
    item, why = rvp.load_scorable(real_log("pxrs_esc_status_log.ulg"), "given")  # PX4 default profile: 9.6 Hz
    assert item is None and "too slow" in why and "9.6 Hz" in why
    item, why = rvp.load_scorable(real_log("pfc_center_0003.bin"), "given")  # ArduPlane log without IMU rows
    assert item is None and why.startswith("not read:") and "IMU" in why
    item, why = rvp.load_scorable(real_log("aplogan_nan.log"), "given")  # its ATT is ~90° from every estimator's tilt
    assert item is None and why.startswith("reference not trusted")
    item, why = rvp.load_scorable(Path("/nonexistent/log.bin"), "given")
    assert item is None and why.startswith("not read:")


def test_a_broad_trial_and_a_drone_log_are_scored_under_their_kind_group_and_label(tmp_path):
    rvp = _rvp()
    (kind, group, name, rec, label), why = rvp.load_scorable(broad_trial("broad_25_*.hdf5"), "seen")
    assert (kind, group, label, why) == ("BROAD", "tapping", "seen", "")
    assert len(rec) > 1000
    (kind, group, name, rec, label), why = rvp.load_scorable(real_log("ardusub_small.BIN"), "held-out")
    assert kind == "drone log" and group.endswith(" 25 Hz") and "ardupilot" in group.lower()


def test_folders_are_expanded_to_their_logs_and_the_split_labels_follow_train_splits(tmp_path):
    rvp = _rvp()
    (tmp_path / "a.BIN").write_bytes(b"x")
    (tmp_path / "b.ulg").write_bytes(b"x")
    (tmp_path / "notes.md").write_text("not a log")
    (tmp_path / "sub").mkdir()
    got = rvp.expand_files([str(tmp_path), "/x/y.tlog"])
    assert [p.name for p in got] == ["a.BIN", "b.ulg", "y.tlog"]
    split = tomllib.loads((REPO / "train/splits/real.toml").read_text())
    listed = set(split["heldout"]["real_logs"]) | set(split["seen"]["broad"])
    shared = real_log("erle_pxf_copter_15-12-2014_16.BIN").parents[1]
    unlisted = rvp.unlisted_shared(shared, listed)
    assert "aplogan_nan.log" in unlisted and "dkla_fs-batt.log" in unlisted
    assert not set(unlisted) & listed


def test_a_record_shorter_than_the_warm_up_is_listed_apart_and_a_file_named_twice_is_scored_once(tmp_path):
    from tepinn_flight.model.synthetic import synthetic_record
    from tepinn_flight.record import write_record

    rvp = _rvp()
    short, long_ = tmp_path / "short.parquet", tmp_path / "long.parquet"
    write_record(synthetic_record(seed=1, duration_s=4.0, rate_hz=100.0), short)
    write_record(synthetic_record(seed=1, duration_s=8.0, rate_hz=100.0), long_)
    item, why = rvp.load_scorable(short, "given")
    assert item is None and why.startswith("nothing to score after the 5-s warm-up")
    (kind, group, name, rec, label), why = rvp.load_scorable(long_, "given")
    assert kind == "simulated" and why == ""
    assert rvp.expand_files([str(tmp_path), str(long_)]) == [long_, short]
