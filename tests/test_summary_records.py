"""The summary's means and the paired comparison are over the same records for every estimator (session 53): a record
on which one estimator has no estimate is kept out of every mean, as the same samples are scored within a record.
Before, it left that estimator's mean alone, which then came from fewer (and other) records than the rest — a
ranking a user would read wrong (`/work/review53/evalcli`, F1)."""

from __future__ import annotations

import numpy as np
import pytest

from tepinn_flight.evaluation.harness import HarnessConfig, evaluate
from tepinn_flight.evaluation.peers import VqfEstimator
from tepinn_flight.evaluation.suite import baseline_estimators
from tepinn_flight.model.synthetic import synthetic_record


class _BlindOn(VqfEstimator):
    """VQF that gives no estimate on the records whose metadata says ``blind`` (a window that never fills)."""

    def __init__(self):
        super().__init__()
        self.name = "blind-vqf"

    def estimate(self, record):
        out = super().estimate(record)
        if record.meta.get("blind"):
            out.loc[:, [c for c in out.columns if c != "t_s"]] = np.nan
        return out


@pytest.fixture(scope="module")
def result():
    a = synthetic_record(seed=1, duration_s=20.0, rate_hz=100.0)
    b = synthetic_record(seed=2, duration_s=20.0, rate_hz=100.0, max_rate_rad_s=8.0, lin_acc_m_s2=6.0)
    b.meta["blind"] = True
    ests = [_BlindOn(), *baseline_estimators()[:1]]
    return evaluate([a, b], ests, HarnessConfig(warmup_s=2.0), progress=False), ests


def test_every_mean_is_over_the_records_every_estimator_scored(result):
    res, (blind, other) = result
    per = {r["name"]: r["results"] for r in res.records}
    assert len(per) == 2
    only = [k for k, v in per.items() if v[blind.name].get("inclination_rmse_deg") is not None
            and np.isfinite(v[blind.name]["inclination_rmse_deg"])]  # fmt: skip
    assert len(only) == 1
    both = [per[k][other.name]["inclination_rmse_deg"] for k in per]
    assert abs(both[0] - both[1]) > 0.1  # the two records do differ
    for e in (blind, other):
        d = res.dataset[e.name]
        assert d["n_records"] == 1
        assert d["inclination_rmse_deg"] == pytest.approx(per[only[0]][e.name]["inclination_rmse_deg"], rel=1e-12)
    assert res.dataset[other.name]["n_records_scored"] == 1
    assert any("not every estimator has an estimate" in n for n in res.notes)


def test_the_record_left_out_stays_in_the_per_record_table(result):
    res, (blind, other) = result
    assert len(res.records) == 2
    assert all(np.isfinite(r["results"][other.name]["inclination_rmse_deg"]) for r in res.records)
