"""The ablation experiment (evaluation/ablation.py) without training: variants, table, arguments."""

from __future__ import annotations

import pytest

from tepinn_flight.errors import ConfigError
from tepinn_flight.evaluation.ablation import (VARIANTS, ablation_markdown, check_variants, heldout_campaign,
                                               variant_config)  # fmt: skip
from tepinn_flight.model.train_config import TrainConfig


def test_variants_remove_one_component_each():
    base = TrainConfig()
    assert variant_config(base, "full") == base
    assert variant_config(base, "no-transformer").model.encoder == "mlp"
    assert variant_config(base, "no-adaptive-weighting").loss.adaptive is False
    lstm = variant_config(base, "lstm-baseline")
    assert lstm.model.encoder == "lstm" and lstm.model.physics is False
    assert set(VARIANTS) >= {"full", "no-physics", "no-uncertainty"}


def test_unknown_variant_is_a_config_error():
    check_variants(["full", "no-physics"])
    with pytest.raises(ConfigError, match="unknown variant"):
        check_variants(["full", "no-such"])


def test_table_has_one_row_per_variant_and_dashes_for_missing_values():
    rows = [{"variant": "full", "inclination_rmse_deg": 1.0, "inclination_rmse_median_deg": 0.9,
             "gyr_bias_rms_deg_s": 0.0123, "nees": 2.1, "vs_full": 1.0},
            {"variant": "vqf", "inclination_rmse_deg": 2.0, "inclination_rmse_median_deg": None,
             "gyr_bias_rms_deg_s": None, "nees": None, "vs_full": 2.0}]  # fmt: skip
    md = ablation_markdown(rows, "train/ablation.toml", 3, notes=["a note"])
    assert md.startswith("# TE-PINN ablation\n")
    assert "evaluated on 3 held-out flights" in md and "`train/ablation.toml`" in md
    assert "| 1.00 | 0.90 | 0.012 | 2.10 | 1.00 |" in md
    assert "| 2.00 | – | – | – | 2.00 |" in md
    assert md.endswith("- a note\n")


def test_default_heldout_campaign_is_in_the_checkout():
    assert heldout_campaign().exists()


def test_an_ablation_whose_variants_all_score_the_same_says_why():
    """With a recipe that keeps the anchored estimator's gates shut on its records, six variants scored 1.34°, ×1.00
    each, and nothing said the table measured no component."""
    from tepinn_flight.evaluation.ablation import IDENTICAL_NOTE, identical_variants

    same = [{"results": {"full": {"inclination_rmse_deg": 1.34}, "no-physics": {"inclination_rmse_deg": 1.34}}}] * 3
    differ = same[:2] + [{"results": {"full": {"inclination_rmse_deg": 1.34}, "no-physics": {"inclination_rmse_deg": 1.5}}}]
    assert identical_variants(same, ["full", "no-physics"]) and not identical_variants(differ, ["full", "no-physics"])
    nothing = [{"results": {"full": {"inclination_rmse_deg": None}, "no-physics": {"inclination_rmse_deg": None}}}]
    nan_first = [{"results": {"full": {"inclination_rmse_deg": float("nan")}, "a": {"inclination_rmse_deg": 1.0},
                              "b": {"inclination_rmse_deg": 5.0}}}]  # fmt: skip
    assert not identical_variants(nothing, ["full", "no-physics"]) and not identical_variants(nan_first, ["full", "a", "b"])
    assert "corrected nothing" in IDENTICAL_NOTE


def test_a_finished_variant_is_taken_only_where_this_recipe_made_it(tmp_path):
    """A variant finished under another recipe (another seed here) is refused in one line naming the keys (review60:
    taken, "already trained", under a header claiming this recipe); under the same recipe it is taken as it is."""
    from tepinn_flight.evaluation.ablation import train_variants
    from tests.test_train import TINY, small_cfg

    base = small_cfg("optim.epochs=1")
    said: list[str] = []
    train_variants(base, ["full"], tmp_path, config_base=TINY.parent, progress=False, say=said.append)
    first = (tmp_path / "full" / "model.pt").read_bytes()
    train_variants(base, ["full"], tmp_path, config_base=TINY.parent, progress=False, say=said.append)
    assert said[-1].startswith("full: already trained") and (tmp_path / "full" / "model.pt").read_bytes() == first
    with pytest.raises(ConfigError, match=r"holds the variant full trained from another recipe \(seed 0 -> 7\)"):
        train_variants(small_cfg("optim.epochs=1", "seed=7"), ["full"], tmp_path, config_base=TINY.parent,
                       progress=False)  # fmt: skip


def test_ablate_refuses_no_variant_and_a_missing_eval_path_before_training(tmp_path, capsys, monkeypatch):
    """`--variants ,` had written a table of VQF alone; a mistyped `--eval` was said after every variant trained
    (about 28 minutes with the default recipe) (review60). The table names the recipe's overrides."""
    import tepinn_flight.evaluation.ablation as A
    from tepinn_flight.cli.main import main
    from tests.test_train import TINY

    def trained(*a, **k):
        raise AssertionError("trained before the arguments were checked")

    monkeypatch.setattr(A, "train_variants", trained)
    assert main(["ablate", "--config", str(TINY), "-o", str(tmp_path / "a"), "--variants", ",", "-q"]) == 2
    assert "--variants names no variant" in capsys.readouterr().err
    assert main(["ablate", "--config", str(TINY), "-o", str(tmp_path / "b"), "--variants", "full",
                 "--eval", str(tmp_path / "nope.parquet"), "-q"]) == 2  # fmt: skip
    assert "no such file or folder" in capsys.readouterr().err
    md = ablation_markdown([], "train/tiny.toml", 3, overrides=["seed=7"])
    assert "Recipe `train/tiny.toml` with `seed=7`, same data" in md
