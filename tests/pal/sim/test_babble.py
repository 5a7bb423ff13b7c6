"""Babbling policies, the data source, ``pal babble`` and ``pal bench babble``."""

import json
import re

import numpy as np
import pytest

from pal.cli import main
from pal.io.dataset import TransitionDataset
from pal.sim.babbling import BabbleConfig, collect, episode_seed, make_source
from pal.sim.policies import OUPolicy, UniformPolicy, make_policy

LOW, HIGH = np.array([-1.0, -0.6875]), np.array([0.33, 1.0])


def test_uniform_policy_covers_the_range_and_is_block_invariant():
    policy = UniformPolicy(LOW, HIGH, np.random.default_rng(0))
    a = policy.sample(20_000)
    assert a.dtype == np.float32 and a.shape == (20_000, 2)
    assert (a >= LOW.astype(np.float32)).all() and (a <= HIGH.astype(np.float32)).all()
    np.testing.assert_allclose(a.mean(0), (LOW + HIGH) / 2, atol=0.02)  # se ~0.003
    np.testing.assert_allclose(a.std(0), (HIGH - LOW) / np.sqrt(12), atol=0.02)
    whole = UniformPolicy(LOW, HIGH, np.random.default_rng(1)).sample(10)
    parts = UniformPolicy(LOW, HIGH, np.random.default_rng(1))
    np.testing.assert_array_equal(np.concatenate([parts.sample(3), parts.sample(7)]), whole)


def test_ou_policy_is_smooth_bounded_and_restorable():
    policy = OUPolicy(LOW, HIGH, np.random.default_rng(0), dt=0.25, theta=1.0, sigma=0.5)
    a = policy.sample(20_000).astype(np.float64)
    assert (a >= LOW - 1e-6).all() and (a <= HIGH + 1e-6).all()
    lag1 = np.corrcoef(a[:-1, 0], a[1:, 0])[0, 1]
    assert lag1 == pytest.approx(np.exp(-0.25), abs=0.05)  # clipping lowers it slightly
    state = json.loads(json.dumps(policy.get_state()))
    expected = policy.sample(5)
    other = OUPolicy(LOW, HIGH, np.random.default_rng(99), dt=0.25)
    other.set_state(state)
    np.testing.assert_array_equal(other.sample(5), expected)


def test_policy_bad_input():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="must be finite with low < high"):
        UniformPolicy(np.array([-np.inf]), np.array([1.0]), rng)
    with pytest.raises(ValueError, match="unknown policy 'brownian'"):
        make_policy("brownian", LOW, HIGH, rng, dt=0.25)
    with pytest.raises(ValueError, match="unknown OU parameter"):
        make_policy("ou", LOW, HIGH, rng, dt=0.25, params={"tau": 1})
    with pytest.raises(ValueError, match="theta must be a finite number > 0"):
        OUPolicy(LOW, HIGH, rng, dt=0.25, theta=0.0)


def test_source_is_deterministic_and_block_size_invariant():
    cfg = BabbleConfig(body="arm", steps=40, seed=3, reset_every=15, chunk_size=40)
    a, b = collect(cfg), collect(BabbleConfig(**{**cfg.__dict__, "chunk_size": 7}))
    for name in a.column_names:
        np.testing.assert_array_equal(a.columns[name], b.columns[name])
    np.testing.assert_array_equal(a.states, b.states)
    c = collect(BabbleConfig(**{**cfg.__dict__, "seed": 4}))
    assert not np.array_equal(a.ctrl, c.ctrl)
    assert len(a.column_names) == 56 and a.states.shape == (40, 25)  # 8 joints x 7 columns
    # every reset_every steps the body starts again from qpos0 at time 0
    resets = a.step % 15 == 0
    assert (a.states[resets, 0] == 0).all() and (a.states[~resets, 0] > 0).all()
    assert episode_seed(3, 1) != episode_seed(3, 2)


def test_recorded_velocities_are_mujocos_and_chain_within_episodes():
    cfg = BabbleConfig(body="finger", steps=30, seed=1, reset_every=10, chunk_size=30)
    loop, batched = collect(cfg), collect(cfg, backend="rollout")
    v_prev, v = loop.columns["v_prev.finger"][:, 0], loop.columns["v.finger"][:, 0]
    np.testing.assert_array_equal(v, batched.columns["v.finger"][:, 0])
    nq = 1  # the finger's one joint: the state is time, qpos, qvel, ...
    np.testing.assert_allclose(v_prev, loop.states[:, 1 + nq], rtol=1e-6)
    within = loop.step[1:] % 10 != 0
    np.testing.assert_array_equal(v_prev[1:][within], v[:-1][within])
    assert np.abs(v).max() > 0.1  # the finger moves


def test_source_yields_single_transitions():
    source = make_source(BabbleConfig(steps=5))
    first = next(iter(source))
    assert set(first) == {"ctrl", "q_prev", "dq_prev", "q", "state", "step", "episode"} and first["step"] == 0
    assert first["dq_prev"].tolist() == [0.0]  # the first step of an episode starts at rest
    assert source.step_index == 1


def test_babble_config_bad_input():
    with pytest.raises(ValueError, match="reset_every must be a positive int"):
        BabbleConfig(reset_every=0)
    with pytest.raises(ValueError, match="unknown policy"):
        BabbleConfig(policy="sine")
    with pytest.raises(ValueError, match="joints must be a tuple of names"):
        BabbleConfig(joints="finger")


def test_pal_babble_cli_smoke(tmp_path, capsys):
    out = tmp_path / "finger"
    assert (
        main(
            [
                "babble",
                "--body",
                "finger",
                "--steps",
                "300",
                "--seed",
                "0",
                "--out",
                str(out),
                "--chunk-size",
                "128",
                "--json",
            ]
        )
        == 0
    )
    summary = json.loads(capsys.readouterr().out)
    assert summary["rows"] == 300 and summary["joints"] == ["finger"]
    ds = TransitionDataset.load(out)
    assert len(ds) == 300 and ds.metadata["policy"]["name"] == "uniform"
    assert -3.3 < summary["q"]["finger"]["min"] < summary["q"]["finger"]["max"] < 0.6
    assert main(["babble", "--steps", "10", "--out", str(out)]) == 2
    assert "already holds a dataset" in capsys.readouterr().err
    assert main(["babble", "--steps", "400", "--out", str(out), "--chunk-size", "128", "--resume"]) == 0
    assert len(TransitionDataset.load(out)) == 400


def test_pal_babble_cli_any_mjcf_and_names(tmp_path, capsys):
    from pal.sim import body_path

    out = tmp_path / "arm"
    assert (
        main(
            [
                "babble",
                "--mjcf",
                str(body_path("arm")),
                "--joint",
                "elbow",
                "--joint",
                "finger",
                "--actuator",
                "elbow",
                "--actuator",
                "finger",
                "--policy",
                "ou",
                "--steps",
                "20",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    ds = TransitionDataset.load(out)
    assert ds.column_names[:5] == ["act.elbow", "q_prev.elbow", "dq_prev.elbow", "dq.elbow", "q.elbow"]
    assert ds.ctrl.shape == (20, 2) and ds.metadata["policy"]["name"] == "ou"
    capsys.readouterr()
    argv = ["babble", "--body", "arm", "--joint", "elbow", "--actuator", "finger", "--steps", "5"]
    assert main([*argv, "--out", str(tmp_path / "idle")]) == 2
    assert "actuator(s) ['finger'] drive no selected joint" in capsys.readouterr().err
    assert not (tmp_path / "idle").exists()
    assert (
        main(["babble", "--body", "arm", "--joint", "knee", "--steps", "5", "--out", str(tmp_path / "x")])
        == 2
    )
    assert re.search(r"unknown joint name\(s\) \['knee'\]", capsys.readouterr().err)
    assert (
        main(
            ["babble", "--mjcf", str(tmp_path / "missing.xml"), "--steps", "5", "--out", str(tmp_path / "y")]
        )
        == 2
    )
    assert re.search("missing.xml.*does not exist", capsys.readouterr().err)
    assert main(["babble", "--body", "arm", "--mjcf", "a.xml", "--out", str(tmp_path / "z")]) == 2
    assert "either --body or --mjcf" in capsys.readouterr().err


@pytest.mark.slow
def test_bench_babble_contract(capsys):
    assert main(["bench", "babble", "--json", "--set", "steps=20", "--set", "repeats=1"]) == 0
    doc = json.loads(capsys.readouterr().out)
    data = doc["metrics"]
    assert {"transitions_per_s", "raw_steps_per_s", "ratio"} <= set(data)
    assert doc["targets"][0]["name"] == "ratio" and doc["targets"][0]["met"] in (True, False)
    assert data["transitions_per_s"] > 0 and data["ratio"] == pytest.approx(
        data["transitions_per_s"] / data["raw_steps_per_s"]
    )


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"seed": -1}, r"seed must be an int in \[0, 4294967295\], got -1"),
        ({"seed": 2**70}, rf"seed must be an int in \[0, 4294967295\], got {2**70}"),
        ({"steps": 10**15}, rf"steps must be an int in \[0, 100000000\], got {10**15}"),
        ({"steps": 10**40}, rf"steps must be an int in \[0, 100000000\], got {10**40}"),
    ],
)
def test_babble_config_refuses_seeds_and_steps_past_the_limits(fields, message):
    with pytest.raises(ValueError, match=message):
        BabbleConfig(**fields)
