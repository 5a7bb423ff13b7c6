"""``pal experiment discovery --body finger|arm``: structure learning on motor-babbling data.

One analysed joint (the finger body, or ``--joint J``): the variables
``act.J, q_prev.J, dq.J, q.J`` of Fig. 5.5 with the tiers ``[act, q_prev] < [dq] < [q]``
(the two-stage predictor of §5.2.1: the displacement is predicted before the position;
without tiers dq and q = q_prev + dq are exchangeable and the JSON also reports that
untiered graph). The learnt graph is fitted with the B1 protocol beside the ``thesis``
and ``state`` graphs on the same split, for every seed in ``b1_seeds`` (MLP initialisation
and minibatch order), and B1 (:func:`pal.experiments.b1.evaluate`) is reported per graph.

Several joints (the arm without ``--joint``): all joints' variables with tiers
``[acts, q_prevs] < [dqs] < [qs]``. Edges are split into within-joint and cross-joint.
Physics is asked by intervening in the simulator on recorded states: the standardised
effect of a parent on ``dq.j`` is

    E_{p -> dq.j} = mean_r |dq_j(p + h) - dq_j(p - h)| / (2h) * sd(p) / sd(dq_j),

with h = 0.05 rad for ``q_prev.k`` (joint k's angle moved before the step) and
h = 0.05 x ctrl range for ``act.k``. A cross-joint edge is *justified* when E >= 0.05.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np
import torch

from inference import fit
from inference.discovery import discover
from models import WorldModel
from models.presets import joint_chain_graph
from pal.data import TransitionDataset
from pal.experiments import b1
from pal.experiments.timing import markdown_table
from pal.experiments.wm_data import DataConfig, JointData, babble_or_load
from pal.experiments.wm_setup import Prepared, ProtocolConfig, build_model
from pal.sim.env import BabblingEnv

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["BodyDiscovery", "physics_effects", "run_body"]

log = logging.getLogger(__name__)

JUSTIFIED = 0.05
TARGET_B1 = 0.10  # learnt-graph q MSE within 10 % of the state graph's


@dataclass(frozen=True)
class BodyDiscovery:
    """Learnt graph(s) of a body and, for one joint, B1 beside the preset graphs."""

    body: str
    joints: list[str]
    learned: dict[str, Any]
    untiered_edges: list[list[str]] | None
    b1: dict[str, dict[str, float]] | None
    b1_per_seed: dict[str, list[dict[str, float]]] | None
    cross_joint: list[dict[str, Any]] | None
    physics: dict[str, float] | None
    seconds: dict[str, float]
    config: dict[str, Any]
    graph_figure: Any = field(default=None, repr=False, compare=False)

    def targets(self) -> dict[str, bool | None]:
        if self.b1 is None:
            return {"q_prev_to_dq": None, "b1_within_10pct_of_state": None}
        j = self.joints[0]
        has = [f"q_prev.{j}", f"dq.{j}"] in [e[:2] for e in self.learned["edge_list"]]
        ratio = self.b1["learned"]["q_mse"] / self.b1["state"]["q_mse"]
        return {"q_prev_to_dq": has, "b1_within_10pct_of_state": ratio <= 1 + TARGET_B1}

    def to_dict(self) -> dict[str, Any]:
        out = {
            "body": self.body,
            "joints": self.joints,
            "learned_edges": self.learned["edge_list"],
            "learned": self.learned["result"],
            "seconds": self.seconds,
            "targets": self.targets(),
        }
        if self.b1 is not None:
            out |= {"b1": self.b1, "b1_per_seed": self.b1_per_seed, "untiered_edges": self.untiered_edges}
        if self.cross_joint is not None:
            out |= {"cross_joint_edges": self.cross_joint, "physics_effects": self.physics}
        return out

    def to_markdown(self) -> str:
        lines = [f"# Structure learning on the `{self.body}` body", ""]
        rows = [[p, c, f"{conf:.3f}", f"{lr:.1f}"] for p, c, conf, lr in self.learned["edge_list"]]
        lines += [
            "Learnt edges:",
            "",
            markdown_table(["parent", "child", "confidence", "log LR [nats]"], rows),
            "",
        ]
        if self.b1 is not None:
            header = ["graph", "dq MSE", "dq MAE", "q MSE", "q MAE"]
            rows = [[g, m.get("dq_mse"), m.get("dq_mae"), m["q_mse"], m["q_mae"]] for g, m in self.b1.items()]
            rows.insert(
                0,
                [
                    "thesis Table 5.7",
                    b1.THESIS["dq"]["mse"],
                    b1.THESIS["dq"]["mae"],
                    b1.THESIS["q"]["mse"],
                    b1.THESIS["q"]["mae"],
                ],
            )
            lines += [
                f"B1 on the test split, mean over fit seeds {self.config['b1_seeds']} (rad², rad):",
                "",
                markdown_table(header, rows),
                "",
            ]
            t = self.targets()
            lines.append(
                f"Targets: learnt graph has q_prev -> dq: {'met' if t['q_prev_to_dq'] else 'NOT met'}; "
                f"learnt-graph q MSE within 10 % of the state graph's: {'met' if t['b1_within_10pct_of_state'] else 'NOT met'}."
            )
            lines.append("")
            if self.untiered_edges is not None:
                lines.append("Without tiers: " + ", ".join(f"{p} -> {c}" for p, c in self.untiered_edges))
                lines.append("")
        if self.cross_joint is not None:
            rows = [
                [e["parent"], e["child"], e["kind"], e["log_ratio"], e["effect"], e["justified"]]
                for e in self.cross_joint
            ]
            lines += [
                f"Cross-joint edges ({len(self.cross_joint)}) with the simulator's standardised effect "
                f"(justified if >= {JUSTIFIED}):",
                "",
                markdown_table(["parent", "child", "kind", "log LR", "physics effect", "justified"], rows)
                if rows
                else "(none)",
                "",
            ]
            strong = sorted(
                ((k, v) for k, v in (self.physics or {}).items() if v >= JUSTIFIED), key=lambda kv: -kv[1]
            )
            lines.append(
                "Cross-joint effects physics has (>= threshold): "
                + (", ".join(f"{k} ({v:.2f})" for k, v in strong) if strong else "none")
            )
            lines.append("")
        return "\n".join(lines)

    def figures(self) -> dict[str, Figure]:
        return {} if self.graph_figure is None else {"graph": self.graph_figure}


def _edge_list(res: Any) -> list[list[Any]]:
    return [[p, c, res.graph.confidence[p, c], res.log_ratio[p, c]] for p, c in res.graph.edges]


def _subsample(cols: dict[str, np.ndarray], n: int, seed: int) -> dict[str, np.ndarray]:
    rows = np.sort(np.random.default_rng(seed).permutation(len(next(iter(cols.values()))))[:n])
    return {k: v[rows].astype(np.float64) for k, v in cols.items()}


def _data_config(config: Any) -> DataConfig:
    joint = config.joint[0] if config.joint and len(config.joint) == 1 else None
    return DataConfig(
        body=config.body or "finger",
        mjcf=config.mjcf,
        joint=joint,
        actuator=config.actuator,
        steps=config.transitions,
        seed=0,
        cache=bool(config.extra.get("cache", True)),
    )


def run_body(config: Any, progress_bar: bool = False) -> BodyDiscovery:
    """The body study (see the module docstring); ``config`` is a discovery ``Config``."""
    start = time.perf_counter()
    dataset = babble_or_load(_data_config(config), progress_bar=progress_bar)
    seconds = {"data": time.perf_counter() - start}
    single = (config.joint is not None and len(config.joint) == 1) or len(dataset.joints) == 1
    if single:
        return _single_joint(config, dataset, seconds, progress_bar)
    return _all_joints(config, dataset, seconds)


def _single_joint(
    config: Any, dataset: TransitionDataset, seconds: dict[str, float], progress_bar: bool
) -> BodyDiscovery:
    joint = JointData.select(dataset, config.joint[0] if config.joint else None)
    train, test = dataset.split(0.8, seed=0)
    q_range = joint.q_range(train)
    graph = joint_chain_graph(
        [joint.joint], {joint.joint: joint.action_range}, "thesis", {joint.joint: q_range}
    )
    act, q_prev, dq, q = joint.names
    cols = joint.columns(train)
    sample = _subsample(cols, int(config.extra.get("discovery_rows", 5000)), seed=0)
    start = time.perf_counter()
    learned = discover(graph, sample, tiers=[[act, q_prev], [dq], [q]], seed=0)
    seconds["discover"] = time.perf_counter() - start
    untiered = discover(graph, sample, seed=0)
    pcfg = ProtocolConfig(
        body=config.body or "finger",
        mjcf=config.mjcf,
        joint=joint.joint,
        actuator=config.actuator,
        steps=config.transitions,
        seed=0,
        epochs=config.epochs,
        batch_size=config.batch_size,
    )
    per_seed: dict[str, list[dict[str, float]]] = {}
    start = time.perf_counter()
    for s in config.b1_seeds:
        prep = Prepared(pcfg, dataset, train, test, joint, q_range)
        for name in ("thesis", "state", "learned"):
            if name == "learned":
                with torch.random.fork_rng():
                    torch.manual_seed(s)
                    model = WorldModel(learned.graph, hidden=pcfg.hidden, activation="tanh")
            else:
                model = build_model(joint, name, q_range, s, pcfg.hidden)
            fit(
                model,
                cols,
                loss="mse",
                epochs=pcfg.epochs,
                batch_size=pcfg.batch_size,
                lr=pcfg.lr,
                seed=s,
                progress_bar=progress_bar,
            )
            prep.models[name] = model
        for g, m in b1.evaluate(prep).items():
            per_seed.setdefault(g, []).append(m)
    seconds["b1_fits"] = time.perf_counter() - start
    mean = {g: {k: float(np.mean([m[k] for m in ms])) for k in ms[0]} for g, ms in per_seed.items()}
    return BodyDiscovery(
        body=str(dataset.metadata.get("body")),
        joints=[joint.joint],
        learned={"edge_list": _edge_list(learned), "result": learned.to_dict()},
        untiered_edges=[list(e) for e in untiered.graph.edges],
        b1=mean,
        b1_per_seed=per_seed,
        cross_joint=None,
        physics=None,
        seconds=seconds,
        config=_config_dict(config),
        graph_figure=learned.graph.plot(),
    )


def _config_dict(config: Any) -> dict[str, Any]:
    keep = ("body", "mjcf", "joint", "actuator", "transitions", "epochs", "batch_size", "b1_seeds", "extra")
    return {k: v for k, v in asdict(config).items() if k in keep}


def physics_effects(
    dataset: TransitionDataset, rows: np.ndarray, source: str, h_angle: float = 0.05, h_ctrl: float = 0.05
) -> dict[str, float]:
    """Standardised simulator effects E_{p -> dq.j} for p in {act.k, q_prev.k}, every j, k (see module docstring)."""
    meta = dataset.metadata
    env = BabblingEnv(
        source, joints=dataset.joints, actuators=dataset.actuators, frame_skip=int(meta["frame_skip"])
    )
    joints = list(dataset.joints)
    acts = {j: env.actuator_names.index(a) for j, a in env.joint_actuators.items() if a in env.actuator_names}
    cols = dataset.columns
    sd_dq = {j: float(cols[f"dq.{j}"].std()) for j in joints}
    out: dict[str, float] = {}

    def dq_after(i: int, move: tuple[str, int, float]) -> np.ndarray:
        env.set_state(dataset.states[i])
        ctrl = dataset.ctrl[i].astype(np.float64)
        kind, k, delta = move
        if kind == "angle":
            env.data.qpos[env.qpos_indices[k]] += delta
            mujoco.mj_forward(env.model, env.data)
        else:
            ctrl[k] = np.clip(ctrl[k] + delta, env.ctrl_low[k], env.ctrl_high[k])
        before = env.data.qpos[env.qpos_indices].copy()
        env.step(ctrl)
        return env.data.qpos[env.qpos_indices] - before

    for kj, k in enumerate(joints):
        parents = [(f"q_prev.{k}", ("angle", kj, h_angle), float(cols[f"q_prev.{k}"].std()))]
        if k in acts:
            a = acts[k]
            h = h_ctrl * float(env.ctrl_high[a] - env.ctrl_low[a])
            parents.append((f"act.{k}", ("ctrl", a, h), float(dataset.ctrl[:, a].std())))
        for name, (kind, idx, h), sd_p in parents:
            diffs = np.array(
                [dq_after(i, (kind, idx, h)) - dq_after(i, (kind, idx, -h)) for i in rows]
            )  # (R, J)
            slope = np.abs(diffs).mean(0) / (2 * h)
            for jj, j in enumerate(joints):
                out[f"{name}->dq.{j}"] = float(slope[jj] * sd_p / sd_dq[j]) if sd_dq[j] > 0 else 0.0
    return out


def _all_joints(config: Any, dataset: TransitionDataset, seconds: dict[str, float]) -> BodyDiscovery:
    meta = dataset.metadata
    joints = [j for j in dataset.joints if j in meta.get("joint_actuators", {})]
    ranges = {j: tuple(meta["actuator_ranges"][meta["joint_actuators"][j]]) for j in joints}
    graph = joint_chain_graph(joints, ranges, "thesis")
    cols = {}
    for j in joints:
        a = dataset.actuators.index(meta["joint_actuators"][j])
        cols[f"act.{j}"] = dataset.ctrl[:, a : a + 1]
        for kind in ("q_prev", "dq", "q"):
            cols[f"{kind}.{j}"] = dataset.columns[f"{kind}.{j}"]
    sample = _subsample(cols, int(config.extra.get("discovery_rows", 4000)), seed=0)
    tiers = [
        [f"act.{j}" for j in joints] + [f"q_prev.{j}" for j in joints],
        [f"dq.{j}" for j in joints],
        [f"q.{j}" for j in joints],
    ]
    start = time.perf_counter()
    learned = discover(graph, sample, tiers=tiers, seed=0)
    seconds["discover"] = time.perf_counter() - start
    start = time.perf_counter()
    rows = np.random.default_rng(1).choice(
        len(dataset), size=min(int(config.extra.get("physics_rows", 100)), len(dataset)), replace=False
    )
    source = config.mjcf or config.body or "finger"
    effects = physics_effects(dataset, rows, source)
    seconds["physics"] = time.perf_counter() - start

    def joint_of(name: str) -> str:
        return name.split(".", 1)[1]

    cross = []
    for p, c in learned.graph.edges:
        if joint_of(p) == joint_of(c):
            continue
        key = f"{p}->dq.{joint_of(c)}" if c.startswith("dq.") else None
        effect = effects.get(key) if key else None
        cross.append(
            {
                "parent": p,
                "child": c,
                # an edge between lag-1 states models the state distribution, not the transition
                "kind": "transition" if c.startswith(("dq.", "q.")) else "state (lag 1)",
                "log_ratio": learned.log_ratio[p, c],
                "effect": effect,
                "justified": None if effect is None else effect >= JUSTIFIED,
            }
        )
    cross_physics = {
        k: v for k, v in effects.items() if joint_of(k.split("->")[0]) != joint_of(k.split("->")[1])
    }
    return BodyDiscovery(
        body=str(meta.get("body")),
        joints=joints,
        learned={"edge_list": _edge_list(learned), "result": learned.to_dict()},
        untiered_edges=None,
        b1=None,
        b1_per_seed=None,
        cross_joint=cross,
        physics=cross_physics,
        seconds=seconds,
        config=_config_dict(config),
        graph_figure=None,
    )
