"""Any MuJoCo body: names with separators, Gymnasium's bodies, frame skip, ranges, datasets, errors."""

from __future__ import annotations

import json
import warnings
from importlib import resources
from pathlib import Path

import gymnasium
import numpy as np
import pyro
import pytest
import torch
from gymnasium.utils.env_checker import check_env

import pal.lab.runner as runner
from inference import FitSchedule
from models import WorldModel, io
from models.presets import joint_chain_graph
from pal.cli import main
from pal.experiments.world_model.data import (
    BodyChoice,
    DataConfig,
    JointData,
    Realizer,
    babble_or_load,
    cache_path,
)
from pal.io.dataset import TransitionDataset
from pal.io.dataset_files import metadata_checksum
from pal.sim import BabblingEnv, load_model
from pal.sim.babbling import BabbleConfig, babble, collect
from pal.sim.body_info import body_info
from pal.sim.env import ENV_ID
from pal.sim.ranges import effective_ranges, parse_action_range

ASSETS = resources.files("gymnasium") / "envs/mujoco/assets"
REACHER = str(ASSETS / "reacher.xml")
PUSHER = str(ASSETS / "pusher.xml")
#: check_env warnings that BabblingEnv documents (unbounded observations, raw ctrl range).
EXPECTED_WARNINGS = ("observation space minimum", "observation space maximum", "symmetric and normalized")

#: Joints named as third-party MJCF files name them; the motor of "joint 1" has no name.
NAMED_BODY = """
<mujoco model="robot:test body">
  <option timestep="0.005"/>
  <worldbody>
    <body name="base">
      <joint name="robot:left_fingers" type="hinge" axis="0 0 1" damping="0.2" range="-1 1"/>
      <geom type="capsule" fromto="0 0 0 0.1 0 0" size="0.01" mass="0.05"/>
      <body name="b2" pos="0.1 0 0">
        <joint name="arm/elbow" type="hinge" axis="0 0 1" damping="0.2"/>
        <geom type="capsule" fromto="0 0 0 0.1 0 0" size="0.01" mass="0.05"/>
        <body name="b3" pos="0.1 0 0">
          <joint name="left-knee" type="slide" axis="1 0 0" damping="2" range="-0.05 0.05"/>
          <geom type="box" size="0.01 0.01 0.01" mass="0.05"/>
          <body name="b4">
            <joint name="joint 1" type="hinge" axis="0 1 0" damping="0.2"/>
            <geom type="capsule" fromto="0 0 0 0 0 0.05" size="0.01" mass="0.02"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="robot:left_fingers" joint="robot:left_fingers" ctrlrange="-1 1" gear="0.05"/>
    <motor name="arm/elbow motor" joint="arm/elbow" ctrlrange="-1 1" gear="0.05"/>
    <motor name="left-knee" joint="left-knee" ctrlrange="-1 1" gear="0.5"/>
    <motor joint="joint 1" ctrlrange="-1 1" gear="0.01"/>
  </actuator>
</mujoco>
"""
JOINTS = ["robot:left_fingers", "arm/elbow", "left-knee", "joint 1"]

#: One hinge, a motor whose force is clamped to half of what its ctrlrange asks for.
FORCE_LIMITED = """
<mujoco model="limited">
  <option timestep="0.01"/>
  <worldbody>
    <body name="link">
      <joint name="hinge" type="hinge" axis="0 0 1" damping="0.5" {joint}/>
      <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02" mass="0.2"/>
    </body>
  </worldbody>
  <actuator>
    <motor name="m" joint="hinge" gear="2" ctrlrange="-1 1" {motor}/>
  </actuator>
</mujoco>
"""


def _write(tmp_path: Path, name: str, text: str) -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


@pytest.fixture
def named_body(tmp_path) -> str:
    return _write(tmp_path, "third_party.xml", NAMED_BODY)


@pytest.fixture
def force_limited(tmp_path) -> str:
    return _write(tmp_path, "limited.xml", FORCE_LIMITED.format(joint="", motor='forcerange="-0.5 0.5"'))


@pytest.fixture(autouse=True)
def _no_cache_in_home(tmp_path, monkeypatch):
    monkeypatch.setenv("PAL_CACHE_DIR", str(tmp_path / "cache"))


@pytest.mark.slow
def test_mujoco_names_work_from_babbling_to_a_saved_world_model(named_body, tmp_path):
    data = collect(BabbleConfig(body=named_body, steps=300, seed=0, frame_skip=4))
    assert data.metadata["body"] == "robot:test body"  # the model's name, not the file stem
    assert data.joints == JOINTS
    assert data.actuators == ["robot:left_fingers", "arm/elbow motor", "left-knee", "joint 1"]
    assert "act.robot:left_fingers" in data.column_names and "dq_prev.joint 1" in data.column_names
    joints = {j: JointData.select(data, j) for j in JOINTS}
    assert joints["arm/elbow"].actuator == "arm/elbow motor" and joints["joint 1"].actuator == "joint 1"
    graph = joint_chain_graph(
        JOINTS,
        {j: d.action_range for j, d in joints.items()},
        "dynamics",
        {j: d.q_range(data) for j, d in joints.items()},
    )
    dot = graph.to_dot()
    assert '"q.joint 1" [label="q.joint 1\\n[rad]"' in dot and '"act.arm/elbow" -> "dq.arm/elbow";' in dot
    assert dot.count(" -> ") == len(graph.edges)
    fig = graph.plot()
    assert {t.get_text() for t in fig.axes[0].texts} >= {"q.left-knee", "dq_prev.robot:left_fingers"}
    columns = {k: v for j, d in joints.items() for k, v in d.columns(data).items() if k in graph}
    model = WorldModel(graph, seed=0)
    from inference import fit

    fit(model, columns, schedule=FitSchedule(epochs=2, batch_size=128), seed=0)
    trace = pyro.poutine.trace(model).get_trace({k: torch.as_tensor(v) for k, v in columns.items()})
    assert {"act.robot:left_fingers", "q.arm/elbow", "dq.left-knee", "q.joint 1"} <= set(trace.nodes)
    path = io.save(model, tmp_path / "model.npz")
    loaded = io.load(path)
    inputs = {k: torch.as_tensor(columns[k][:20]) for k in graph.roots}
    for name, value in model.predict(inputs).items():
        torch.testing.assert_close(loaded.predict(inputs)[name], value, rtol=0, atol=0, msg=name)
    # replay on the recorded states reproduces the recorded outcome of "arm/elbow"
    realizer = Realizer(data, joints["arm/elbow"], named_body)
    rows = np.arange(3, 300, 37)
    recorded = data.columns["q.arm/elbow"][rows, 0]
    np.testing.assert_allclose(realizer.outcomes(rows, data.ctrl[rows, 1]), recorded, atol=1e-6)


def test_unnamed_actuators_are_called_after_their_joints_and_the_name_comes_from_the_model(tmp_path):
    info = body_info(REACHER)
    assert info.name == "reacher" and info.actuators == ("joint0", "joint1")
    assert info.joints == ("joint0", "joint1", "target_x", "target_y")
    assert info.joint_actuators == {"joint0": "joint0", "joint1": "joint1"}
    copy = _write(tmp_path, "finger.xml", Path(REACHER).read_text())
    assert load_model(copy).name == "reacher"  # not the file stem "finger"
    assert load_model(copy, name="my reacher").name == "my reacher"
    unnamed = _write(tmp_path, "pendulum.xml", NAMED_BODY.replace(' model="robot:test body"', ""))
    assert load_model(unnamed).name == "pendulum"  # only a model without a name falls back to the stem
    with pytest.raises(ValueError, match="body name ' padded' is not a usable name"):
        load_model(copy, name=" padded")


@pytest.mark.parametrize("path", [REACHER, PUSHER], ids=["reacher", "pusher"])
def test_gymnasium_bodies_pass_the_env_checker_and_replay_exactly(path):
    env = gymnasium.make(ENV_ID, model=path, frame_skip=5).unwrapped
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env)
    assert [str(w.message) for w in caught if not any(e in str(w.message) for e in EXPECTED_WARNINGS)] == []
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    states, actions, after = [], [], []
    for _ in range(8):
        states.append(env.get_state())
        actions.append(rng.uniform(env.ctrl_low, env.ctrl_high))
        after.append(env.step(actions[-1])[0])
    fresh = BabblingEnv(path, frame_skip=5)
    for i in (5, 0, 7):
        fresh.set_state(states[i])
        np.testing.assert_array_equal(fresh.step(actions[i])[0], after[i])


def test_pal_babble_reacher_reports_the_step_and_the_effective_ranges(tmp_path, capsys):
    out = tmp_path / "reacher"
    argv = ["babble", "--mjcf", REACHER, "--joint", "joint0", "--joint", "joint1", "--frame-skip", "5"]
    assert main([*argv, "--steps", "400", "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["body"] == "reacher" and summary["actuators"] == ["joint0", "joint1"]
    assert summary["frame_skip"] == 5 and summary["dt"] == pytest.approx(0.05)
    assert set(summary["effective_ranges"]) == {"joint0", "joint1"}
    assert summary["effective_ranges"]["joint0"]["ctrlrange"] == [-1.0, 1.0]
    meta = TransitionDataset.load(out).metadata
    assert meta["effective_ranges"] == summary["effective_ranges"] and meta["dt"] == pytest.approx(0.05)
    assert main([*argv, "--steps", "50", "--out", str(tmp_path / "text")]) == 0
    assert "joint0: babbled [-1, 1], effective" in capsys.readouterr().out


@pytest.mark.parametrize("where", ["actuator", "joint"])
def test_a_force_limit_is_found_in_the_data_and_in_the_model(tmp_path, where):
    if where == "actuator":  # force = ctrl clamped to +-0.5: commands beyond +-0.5 change nothing
        xml, limit = FORCE_LIMITED.format(joint="", motor='forcerange="-0.5 0.5"'), 0.5
    else:  # joint torque = 2 ctrl clamped to +-0.6: commands beyond +-0.3 change nothing
        xml, limit = FORCE_LIMITED.format(joint='actuatorfrcrange="-0.6 0.6"', motor=""), 0.3
    body = _write(tmp_path, "limited.xml", xml)
    data = collect(BabbleConfig(body=body, steps=2000, seed=0, frame_skip=5))
    found = data.metadata["effective_ranges"]["m"]
    assert found["force_limit"] == pytest.approx([-limit, limit])
    np.testing.assert_allclose(found["measured"], [-limit, limit], atol=0.03)  # the data alone agree
    assert found["saturated_fraction"] == pytest.approx(1 - limit, abs=0.03)
    data.metadata["actuator_force_limits"] = {"m": None}  # without the model's word, from the data only
    np.testing.assert_allclose(effective_ranges(data)["m"]["effective"], [-limit, limit], atol=0.03)


def test_no_saturation_is_claimed_where_the_response_stays_linear():
    data = collect(BabbleConfig(body=REACHER, joints=("joint0",), steps=3000, seed=0, frame_skip=5))
    found = data.metadata["effective_ranges"]["joint0"]  # an unlimited hinge with a plain motor
    assert found["effective"] == [-1.0, 1.0] and found["saturated_fraction"] == 0.0


def test_babbling_can_be_restricted_to_the_effective_or_a_given_range(force_limited):
    base = BabbleConfig(body=force_limited, steps=300, seed=1, frame_skip=5, probe_steps=1500)
    auto = collect(BabbleConfig(**{**base.__dict__, "effective_range": True}))
    low, high = auto.metadata["action_ranges"]["m"]
    assert low == pytest.approx(-0.5, abs=0.03) and high == pytest.approx(0.5, abs=0.03)
    assert auto.ctrl.min() >= np.float32(low) and auto.ctrl.max() <= np.float32(high)
    assert auto.metadata["effective_range_probe"]["steps"] == 1500
    given = collect(BabbleConfig(**{**base.__dict__, "action_ranges": (("m", -0.2, 0.4),)}))
    assert given.metadata["action_ranges"]["m"] == [-0.2, 0.4]
    assert given.ctrl.min() >= np.float32(-0.2) and given.ctrl.max() <= np.float32(0.4)
    assert JointData.select(given).action_range == (-0.2, 0.4)  # the world model's X_a
    assert given.metadata["effective_ranges"]["m"]["babbled"] == [-0.2, 0.4]


def test_body_choice_carries_every_option_and_checks_it_when_built():
    choice = BodyChoice(mjcf=REACHER, joint="joint1", frame_skip=5, action_range=(("joint1", -0.5, 0.5),))
    assert choice.analysed() == ("joint1", "joint1") and choice.info().timestep == 0.01
    cfg = choice.babble_config(100, 3)
    assert (cfg.frame_skip, cfg.action_ranges, cfg.body) == (5, (("joint1", -0.5, 0.5),), REACHER)
    bad = [
        ({"joint": "elbow"}, r"unknown joint 'elbow'; the joints of body 'reacher'"),
        ({"actuator": ("thumb",)}, r"unknown actuator\(s\) \['thumb'\]"),
        ({"joint": "target_x"}, "no babbling actuator drives joint 'target_x'"),
        ({"joint": "joint0", "actuator": ("joint1",)}, "no babbling actuator drives joint 'joint0'"),
        ({"frame_skip": 0}, "frame_skip must be a positive int, got 0"),
        ({"action_range": (("joint0", -2.0, 0.5),)}, r"lies outside the ctrlrange \[-1.0, 1.0\]"),
        ({"action_range": (("target_x", -0.5, 0.5),)}, "not a babbling actuator"),
        ({"action_range": (("joint0", 0.5, -0.5),)}, "expected finite numbers LOW < HIGH"),
        ({"name": "two\nlines"}, "is not a usable name"),
        ({"mjcf": "/nonexistent/body.xml"}, "/nonexistent/body.xml' does not exist"),
    ]
    for fields, match in bad:
        with pytest.raises(ValueError, match=match):
            BodyChoice(**{"mjcf": REACHER, **fields})
    with pytest.raises(ValueError, match="name the one to analyse"):
        DataConfig(BodyChoice(mjcf=REACHER)).check()
    assert parse_action_range("robot:a=b=-0.5,1") == ("robot:a=b", -0.5, 1.0)
    with pytest.raises(ValueError, match="is not NAME=LOW,HIGH"):
        parse_action_range("joint0:-1,1")


def test_the_cache_key_holds_name_frame_skip_and_ranges(tmp_path):
    base = BodyChoice(mjcf=REACHER, joint="joint0", actuator=("joint0",))
    paths = {
        cache_path(DataConfig(b, steps=100, cache_dir=str(tmp_path)), 0)
        for b in (
            base,
            BodyChoice(**{**base.__dict__, "frame_skip": 5}),
            BodyChoice(**{**base.__dict__, "action_range": (("joint0", -0.5, 0.5),)}),
            BodyChoice(**{**base.__dict__, "effective_range": True}),
            BodyChoice(**{**base.__dict__, "name": "reacher two"}),
        )
    }
    assert len(paths) == 5
    names = sorted(p.name.split("-n100-")[0] for p in paths)
    assert names == ["reacher"] * 4 + ["reacher_two"]


def test_an_existing_dataset_is_used_and_a_foreign_one_refused(tmp_path):
    root = tmp_path / "data"
    babble(
        BabbleConfig(
            body=REACHER, joints=("joint0", "joint1"), steps=60, seed=2, frame_skip=5, chunk_size=30
        ),
        root,
    )
    body = BodyChoice(mjcf=REACHER, joint="joint0", frame_skip=5)
    config = DataConfig(body, dataset=str(root))
    data = babble_or_load(config, seed=9)  # the seed and steps do not matter: nothing is babbled
    np.testing.assert_array_equal(data.ctrl, TransitionDataset.load(root).ctrl)
    assert not (tmp_path / "cache").exists()
    refused = [
        (BodyChoice(joint="finger", frame_skip=5), "was recorded from body 'reacher'"),
        (BodyChoice(mjcf=REACHER, joint="joint0"), "recorded with frame skip 5, the experiment uses 50"),
        (
            BodyChoice(mjcf=REACHER, joint="joint0", actuator=("joint0",), frame_skip=5),
            "babbled the actuators",
        ),
        (
            BodyChoice(mjcf=REACHER, joint="joint0", frame_skip=5, action_range=(("joint0", -0.5, 0.5),)),
            "babbled other command ranges",
        ),
    ]
    for choice, match in refused:
        with pytest.raises(ValueError, match=match):
            DataConfig(choice, dataset=str(root))
    with pytest.raises(ValueError, match="is not a directory"):
        DataConfig(body, dataset=str(tmp_path / "none"))
    meta = {**json.loads((root / "metadata.json").read_text()), "complete": False}
    (root / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="metadata_checksum .* does not match its content"):
        DataConfig(body, dataset=str(root))  # an edit without the checksum
    (root / "metadata.json").write_text(json.dumps({**meta, "metadata_checksum": metadata_checksum(meta)}))
    with pytest.raises(ValueError, match="is incomplete"):
        DataConfig(body, dataset=str(root))


class _Captured(Exception):
    """Raised instead of running the entry, carrying its config."""


@pytest.fixture
def no_run(monkeypatch):
    def capture(entry, config, **kwargs):
        raise _Captured(config)

    monkeypatch.setattr(runner, "execute", capture)


def _config(argv):
    with pytest.raises(_Captured) as caught:
        main(argv)
    return caught.value.args[0]


def test_experiment_body_flags_equal_the_settings_they_stand_for(no_run):
    flags = ["experiment", "b1", "--mjcf", REACHER, "--joint", "joint1", "--frame-skip", "5"]
    flags += ["--action-range", "joint1=-0.5,0.5", "--name", "reacher 5"]
    sets = ["experiment", "b1", "--set", f"protocol.data.body.mjcf={REACHER}"]
    sets += ["--set", "protocol.data.body.joint=joint1", "--set", "protocol.data.body.frame_skip=5"]
    sets += ["--set", 'protocol.data.body.action_range=[["joint1", -0.5, 0.5]]']
    sets += ["--set", "protocol.data.body.name=reacher 5"]
    assert _config(flags) == _config(sets)
    body = _config(flags).protocol.data.body
    assert (body.frame_skip, body.action_range, body.name) == (5, (("joint1", -0.5, 0.5),), "reacher 5")
    bench = _config(["bench", "babble", "--mjcf", REACHER, "--frame-skip", "5", "--effective-range"]).body
    assert (bench.mjcf, bench.frame_skip, bench.effective_range) == (REACHER, 5, True)
    # a new body drops the old body's joint and actuators
    arm = _config(["experiment", "discovery_body", "--quick", "--body", "arm"]).protocol.data.body
    assert (arm.body, arm.actuator, arm.joint) == ("arm", None, None)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["babble", "--mjcf", REACHER, "--joint", "knee"], r"unknown joint name(s) ['knee']"),
        (["babble", "--mjcf", "/nonexistent/body.xml"], "'/nonexistent/body.xml' does not exist"),
        (
            ["babble", "--mjcf", REACHER, "--joint", "joint0", "--actuator", "joint1"],
            "drive no selected joint",
        ),
        (["babble", "--mjcf", REACHER, "--action-range", "joint0=-2,1"], "outside the ctrlrange [-1.0, 1.0]"),
        (["babble", "--mjcf", REACHER, "--action-range", "joint0=1"], "is not NAME=LOW,HIGH"),
        (["babble", "--mjcf", REACHER, "--frame-skip", "0"], "frame_skip must be a positive int, got 0"),
        (["babble", "--mjcf", REACHER, "--name", " x"], "body name ' x' is not a usable name"),
        (["experiment", "b1", "--mjcf", REACHER], "name the one to analyse (--joint NAME)"),
        (["experiment", "b1", "--mjcf", REACHER, "--joint", "target_x"], "no babbling actuator drives joint"),
        (
            ["experiment", "b2", "--mjcf", REACHER, "--joint", "joint0", "--frame-skip", "0"],
            "frame_skip must be",
        ),
        (
            ["experiment", "b1", "--mjcf", REACHER, "--joint", "joint0", "--action-range", "joint0=0,3"],
            "outside",
        ),
        (
            ["experiment", "b1", "--set", "protocol.data.body.frame_skip=0"],
            "frame_skip must be a positive int",
        ),
        (["experiment", "b1", "--dataset", "/nonexistent/data"], "is not a directory"),
        (["experiment", "b1", "--mjcf", REACHER, "--joint", "joint0", "--name", ""], "is not a usable name"),
        (["bench", "babble", "--dataset", "d"], "--dataset: pal bench babble has no dataset setting"),
        (["bench", "babble", "--mjcf", REACHER, "--actuator", "thumb"], "unknown actuator(s) ['thumb']"),
        (["experiment", "explore", "--body", "arm", "--mjcf", REACHER], "either --body or --mjcf"),
    ],
)
def test_bad_choices_fail_in_one_line_before_babbling(argv, message, tmp_path, capsys, monkeypatch, no_run):
    monkeypatch.chdir(tmp_path)
    if argv[0] == "babble":
        argv = [*argv, "--steps", "20", "--out", str(tmp_path / "out")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and message in err, err
    assert not (tmp_path / "out").exists() and not (tmp_path / "cache").exists()


def test_experiment_refuses_a_dataset_of_another_frame_skip(tmp_path, capsys, no_run):
    root = tmp_path / "finger5"
    babble(BabbleConfig(steps=30, seed=0, frame_skip=5, chunk_size=30), root)
    assert main(["experiment", "b1", "--dataset", str(root)]) == 2
    assert (
        "recorded with frame skip 5, the experiment uses 50; pass --frame-skip 5" in capsys.readouterr().err
    )
    config = _config(["experiment", "b1", "--dataset", str(root), "--frame-skip", "5"])
    assert config.protocol.data.dataset == str(root) and config.protocol.data.body.frame_skip == 5


@pytest.mark.slow
def test_bench_babble_runs_on_a_gymnasium_body(capsys):
    argv = ["bench", "babble", "--mjcf", REACHER, "--frame-skip", "5", "--json"]
    assert main([*argv, "--set", "steps=20", "--set", "repeats=1", "--set", "record=false"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["metrics"]["body"] == "reacher" and doc["metrics"]["frame_skip"] == 5
    assert doc["config"]["body"]["frame_skip"] == 5


def test_dot_and_plots_quote_every_printable_name():
    from models import CausalGraph, Variable

    names = ['act.say "hi"', "q.back\\slash", "q.$cost$"]
    graph = CausalGraph(
        [
            Variable(names[0], "action", bounds=(-1, 1)),
            Variable(names[1], "latent"),
            Variable(names[2], "latent"),
        ],
        [(names[0], names[1]), (names[1], names[2])],
    )
    dot = graph.to_dot()
    assert '"act.say \\"hi\\"" -> "q.back\\\\slash";' in dot and '"q.back\\\\slash" -> "q.$cost$";' in dot
    fig = graph.plot()
    fig.canvas.draw()
    # drawn as written: a pair of "$" would otherwise be typeset as matplotlib mathtext
    assert {t.get_text() for t in fig.axes[0].texts} >= {"q.\\$cost\\$", 'act.say "hi"'}


def test_a_relative_mjcf_is_recorded_as_an_absolute_resolved_path(tmp_path, monkeypatch):
    src = resources.files("pal.sim") / "assets" / "finger.xml"
    (tmp_path / "finger.xml").write_bytes(src.read_bytes())
    monkeypatch.chdir(tmp_path)
    loaded = load_model("./finger.xml")
    assert loaded.path == (tmp_path / "finger.xml").resolve() and loaded.path.is_absolute()
    assert len(loaded.sha256) == 64
