"""``benchmarks/broad_cv.py`` holds each fold's trials out of that fold's training: the command it runs,
read back through the recipe loader and the training's own file resolution, names every other trial
and none of the fold's (the README's cross-validated BROAD figure rests on it)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from tepinn_flight.model.train_config import load_train_config
from tepinn_flight.model.train_data import resolve_records

REPO = Path(__file__).resolve().parents[1]
NAMES = ["01_undisturbed_slow_rotation_A", "03_undisturbed_slow_rotation_C", "05_undisturbed_slow_rotation_with_breaks_B",
         "06_undisturbed_fast_rotation_A", "08_undisturbed_fast_rotation_with_breaks_A", "10_undisturbed_slow_translation_A",
         "12_undisturbed_slow_translation_C", "15_undisturbed_fast_translation_A", "18_undisturbed_fast_translation_with_breaks_B",
         "25_disturbed_tapping_B", "26_disturbed_phone_vibration_A", "28_disturbed_stationary_magnet_A",
         "31_disturbed_stationary_magnet_D", "32_disturbed_attached_magnet_1cm", "34_disturbed_attached_magnet_3cm",
         "35_disturbed_attached_magnet_4cm", "36_disturbed_attached_magnet_5cm"]  # fmt: skip


def _cv():
    spec = importlib.util.spec_from_file_location("broad_cv", REPO / "benchmarks/broad_cv.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _motion_class(name: str) -> str:
    w = name.split("_")[1:]
    return "_".join(w[:3] if w[0] == "undisturbed" else w[:2])  # undisturbed_fast_rotation, disturbed_tapping


def test_the_folds_split_the_shared_trials_once_each_and_each_fold_trains_on_every_class_with_two_trials():
    cv = _cv()
    held = [t for f in cv.FOLDS.values() for t in f]
    assert sorted(held) == sorted(n[:2] for n in NAMES)  # each trial in exactly one fold
    classes = {n[:2]: _motion_class(n) for n in NAMES}
    assert len(set(classes.values())) == 8
    several = {c for c in classes.values() if list(classes.values()).count(c) >= 2}
    for fold in cv.FOLDS:
        trained = {classes[n[:2]] for n in NAMES if n[:2] not in cv.FOLDS[fold]}
        assert several <= trained, fold  # tapping and vibration have one trial each: one fold holds each out


@pytest.mark.parametrize("fold", ["A", "B", "C"])
def test_a_folds_training_command_names_every_other_trial_and_none_of_its_own(tmp_path, fold):
    cv = _cv()
    trials = []
    for n in NAMES:
        p = tmp_path / "with space" / f"broad_{n}.hdf5"
        p.parent.mkdir(exist_ok=True)
        p.write_bytes(b"")
        trials.append(p)
    cmd = cv.train_command(trials, fold, tmp_path / "run", 3, ["--device", "cpu"])
    sets = [cmd[i + 1] for i, a in enumerate(cmd) if a == "--set"]
    cfg = load_train_config(REPO / "train/default.toml", sets)
    assert cfg.seed == 3 and cmd[-2:] == ["--device", "cpu"]
    found = []
    for pat in cfg.data.optional_records:
        found += resolve_records([pat], REPO / "train")
    got = sorted(cv.trial_number(p) for p in found)
    assert got == sorted(n[:2] for n in NAMES if n[:2] not in cv.FOLDS[fold])
    assert not set(got) & set(cv.FOLDS[fold])
    assert "--resume" not in cmd
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "last.pt").write_bytes(b"")
    assert cv.train_command(trials, fold, tmp_path / "run", 3, [])[-1] == "--resume"
