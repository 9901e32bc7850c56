"""`hybsim run --parquet`: pandas reads the samples and jumps tables as they
are, with the CSV's columns and values (bit for bit), typed."""

import subprocess

import numpy as np
import pytest

pd = pytest.importorskip("pandas")
pytest.importorskip("pyarrow")


@pytest.mark.parametrize(
    "model, flags",
    [
        ("bouncing_ball.hyb", ["--J", "12"]),
        # Its events in full, then as its `log` block has them: marks
        # (jump records without pre- and post-jump rows).
        ("consensus_estimation.hyb",
         ["--T", "0.3", "--log-every", "3", "--log-rules", "event"]),
        ("consensus_estimation.hyb", ["--T", "0.3", "--log-every", "3"]),
    ],
)
def test_parquet_equals_csv(hybsim_bin, models, tmp_path, model, flags):
    csv, parquet = tmp_path / "r.csv", tmp_path / "r.parquet"
    subprocess.run(
        [str(hybsim_bin), "run", str(models / model), "-q", "--no-mcap",
         "--csv", str(csv), "--parquet", str(parquet), *flags],
        check=True,
    )
    table = pd.read_parquet(parquet)
    # Text cells parsed by Python's float(), which rounds correctly.
    text = pd.read_csv(csv, dtype=str, keep_default_na=False)
    assert list(table.columns) == list(text.columns)
    assert table["j"].dtype == np.uint64 and table["t"].dtype == np.float64
    assert (table["kind"] == text["kind"]).all()
    for name in table.columns.drop(["j", "kind"]):
        # Bit for bit: the float64 patterns are equal.
        a = table[name].to_numpy(np.float64).view(np.uint64)
        b = np.array([float(v) for v in text[name]]).view(np.uint64)
        assert (a == b).all(), name
    jumps = pd.read_parquet(tmp_path / "r.jumps.parquet")
    assert list(jumps.columns[:4]) == ["t", "j", "rule", "rule_id"]
    assert len(jumps) >= (table["kind"] == "pre_jump").sum()
    assert len(jumps) > 0
