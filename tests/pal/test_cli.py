import json

import pytest

from pal.cli import main


def test_demo_quick_writes_figures_and_summary(tmp_path, capsys):
    assert main(["demo", "--quick", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "do(X=0): Y_cf = 0.5000 [0.5], Z_cf = 0.0000 [0.0]" in out
    summary = json.loads((tmp_path / "demo.json").read_text())
    # the graph with q_prev -> dq predicts the spring finger far better than Fig. 5.5
    assert summary["b1"]["state"]["q_mse"] < 0.2 * summary["b1"]["thesis"]["q_mse"]
    for name in (
        "action_inference.png",
        "curiosity.png",
        "graph_thesis.png",
        "fit_state.png",
        "world_model_state.npz",
        "perception_trajectories.png",
        "loop.mp4",
    ):
        assert (tmp_path / name).stat().st_size > 0, name


def test_unknown_names_and_bad_arguments(capsys):
    with pytest.raises(SystemExit, match="unknown bench 'nope'"):
        main(["bench", "nope"])
    with pytest.raises(SystemExit, match="--threads must be >= 1"):
        main(["--threads", "0", "demo"])
    with pytest.raises(SystemExit, match="pal experiment b1: unknown body 'hand'"):
        main(["experiment", "b1", "--quick", "--body", "hand"])
    with pytest.raises(SystemExit, match="--mjcf: pal.experiments.bench_svi has no 'mjcf' setting"):
        main(["bench", "svi", "--mjcf", "x.xml"])
