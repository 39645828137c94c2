"""``csv_table.write_csv``: what pandas (the reader an analyst's script uses) reads back is the table, bit for bit."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pyarrow as pa

from tepinn_flight.csv_table import write_csv


def test_floats_nan_and_missing_values_read_back_as_written(tmp_path):
    rng = np.random.default_rng(3)
    x = rng.standard_normal(3000) * 10.0 ** rng.integers(-12, 12, 3000)  # every magnitude, both signs
    x[::7] = np.nan
    x[5], x[6] = 0.1, -0.0
    df = pd.DataFrame({"t_s": np.arange(3000) / 400.0, "q_est_w": x, "n": np.arange(3000) - 1500,
                       "clipped": np.arange(3000) % 3 == 0})  # fmt: skip
    table = pa.Table.from_pandas(df, preserve_index=False)
    table = table.append_column("gap", pa.array([None if i % 5 else 1.5 for i in range(3000)], pa.float64()))
    write_csv(table, tmp_path / "t.csv")
    text = (tmp_path / "t.csv").read_text()
    assert text.splitlines()[0] == "t_s,q_est_w,n,clipped,gap"  # the names as they are, unquoted
    back = pd.read_csv(tmp_path / "t.csv")
    for c in ("t_s", "q_est_w", "gap"):
        want = table.column(c).to_numpy(zero_copy_only=False).astype(np.float64)
        assert np.array_equal(back[c].to_numpy(np.float64), want, equal_nan=True), c
    assert np.isnan(back["q_est_w"].to_numpy()[::7]).all() and np.isnan(back["gap"].to_numpy()[1:5]).all()
    assert (back["n"].to_numpy() == df["n"].to_numpy()).all() and (back["clipped"].to_numpy() == df["clipped"]).all()
    assert np.signbit(back["q_est_w"][6])  # −0.0 stays negative
