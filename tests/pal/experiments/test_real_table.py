"""The real-table structure entry: loading, names, bad files, and a run on a small written table."""

import numpy as np
import pandas as pd
import pytest

from pal.experiments.structure.real_table import Config, load, run, variable_name


def _write(tmp_path, n=300, seed=0):
    """x -> y -> z with strong links, columns labelled like cytometry markers."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=n)
    y = 2.0 * x + 0.3 * rng.normal(size=n)
    z = -1.5 * y + 0.3 * rng.normal(size=n)
    path, truth = tmp_path / "table.csv", tmp_path / "truth.csv"
    pd.DataFrame({"PKA": x, "p44/42": y, "Z": z}).to_csv(path, index=False)
    pd.DataFrame({"Cause": ["PKA", "p44/42"], "Effect": ["p44/42", "Z"]}).to_csv(truth, index=False)
    return str(path), str(truth)


def test_names_and_edges_are_read_alike(tmp_path):
    assert variable_name("p44/42") == "p44_42" and variable_name("PKA") == "pka"
    table, edges = load(*_write(tmp_path))
    assert list(table) == ["pka", "p44_42", "z"] and table["pka"].shape == (300,)
    assert edges == [("pka", "p44_42"), ("p44_42", "z")]


def test_bad_files_name_the_problem(tmp_path):
    path, truth = _write(tmp_path)
    with pytest.raises(ValueError, match="is not a file"):
        load(str(tmp_path / "missing.csv"), truth)
    bad = tmp_path / "bad.csv"
    pd.DataFrame({"a": [1.0, "x"], "b": [1.0, 2.0]}).to_csv(bad, index=False)
    with pytest.raises(ValueError, match="column 'a'.*non-numeric"):
        load(str(bad), truth)
    three = tmp_path / "three.csv"
    pd.DataFrame({"a": ["PKA"], "b": ["Z"], "c": [1]}).to_csv(three, index=False)
    with pytest.raises(ValueError, match="3 columns, expected 2"):
        load(path, str(three))
    other = tmp_path / "other.csv"
    pd.DataFrame({"Cause": ["PKA"], "Effect": ["raf"]}).to_csv(other, index=False)
    with pytest.raises(ValueError, match=r"truth names \['raf'\] are not columns"):
        load(path, str(other))
    with pytest.raises(ValueError, match="give both path and truth"):
        run(Config(path=path))
    with pytest.raises(ValueError, match="rows=500 is more than the table's 300 rows"):
        run(Config(path=path, truth=truth, rows=500, subsamples=1, peers=False))


def test_a_run_on_a_written_table_scores_discover_against_the_empty_graph(tmp_path):
    path, truth = _write(tmp_path)
    report = run(Config(path=path, truth=truth, rows=200, subsamples=1, peers=False))
    mean = report.metrics["mean"]
    # a linear Gaussian chain: its two edges are found, their orientation is not identifiable
    assert mean["empty"] == 2.0 and mean["pal_edges"] == 2.0 and mean["pal"] <= 2.0
    target = report.target("shd_minus_empty")
    assert target.evaluated and target.value == pytest.approx(mean["pal"] - 2.0)
    assert report.target("shd_minus_pc").verdict == "not evaluated"
