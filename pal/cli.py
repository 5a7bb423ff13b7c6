"""The ``pal`` command.

pal demo [--out DIR] [--quick]
pal bench NAME [--json] [--out DIR]
pal experiment NAME [--json] [--out DIR] [--quick]
pal babble [--body finger|arm | --mjcf PATH] [--joint J ...] [--actuator A ...] --steps N --seed S
           --out DIR [--policy uniform|ou] [--resume] [--json]
pal record --motion MOTION --seed S --out DIR [--fps F] [--width W] [--height H] [--overwrite] [--json]
pal loop --steps N [--video out.mp4] [--babble B] [--goal X,Y] [--seed S] [--json]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

__all__ = ["main"]

#: ``pal experiment|bench`` flags that set the config field of the same name when given
BODY_FLAGS = ("body", "mjcf", "joint", "actuator")


def _configure(verbose: bool, threads: int) -> None:
    os.environ.setdefault("MPLBACKEND", "Agg")
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, str(threads))  # before numpy/torch load their thread pools
    import torch

    # The models work on small tensors: one intra-op thread is faster, and OpenMP threads
    # slow down by orders of magnitude when another process holds the second core.
    torch.set_num_threads(threads)
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )


def _config_from_args(module: Any, args: argparse.Namespace) -> Any:
    config = module.Config()
    if getattr(args, "quick", False):
        if not hasattr(module.Config, "quick"):
            raise SystemExit(f"{module.__name__} has no --quick configuration")
        config = module.Config.quick()
    overrides = {}
    names = {f.name for f in fields(config)}
    for flag in BODY_FLAGS:
        value = getattr(args, flag, None)
        if value is None:
            continue
        if flag not in names:
            raise SystemExit(f"--{flag}: {module.__name__} has no {flag!r} setting")
        overrides[flag] = tuple(value) if isinstance(value, list) else value
    for item in getattr(args, "set", None) or []:
        key, sep, raw = item.partition("=")
        if not sep or key not in names:
            raise SystemExit(f"--set {item!r}: expected KEY=VALUE with KEY one of {sorted(names)}")
        try:
            overrides[key] = json.loads(raw)
        except json.JSONDecodeError:
            overrides[key] = raw
    return replace(config, **overrides) if overrides else config


def _run_registered(kind: str, args: argparse.Namespace) -> int:
    from pal.experiments import load_module
    from pal.experiments.output import jsonable, write_outputs

    try:
        module = load_module(kind, args.name)
    except ValueError as err:
        raise SystemExit(str(err)) from None
    try:
        config = _config_from_args(module, args)
    except (ValueError, TypeError) as err:  # a config field out of range or of the wrong type
        raise SystemExit(f"pal {kind} {args.name}: {err}") from None
    start = time.perf_counter()
    result = module.run(config, progress_bar=not args.json and sys.stderr.isatty())
    elapsed = time.perf_counter() - start
    data = result.to_dict()
    if args.out:
        figures = result.figures() if hasattr(result, "figures") else {}
        paths = write_outputs(
            args.out, args.name, data, result.to_markdown(), figures, jsonable(vars(config))
        )
        logging.getLogger("pal").info("wrote %s", ", ".join(str(p) for p in paths.values()))
    if args.json:
        print(json.dumps(jsonable(data), indent=2, sort_keys=True))
    else:
        print(result.to_markdown())
        print(f"\n({kind} {args.name} took {elapsed:.1f} s)")
    return 0


def _demo(args: argparse.Namespace) -> int:
    from pal.experiments import demo

    config = demo.Config.quick() if args.quick else demo.Config()
    config = replace(config, out_dir=str(Path(args.out)))
    start = time.perf_counter()
    for line in demo.run(config, progress_bar=sys.stderr.isatty()):
        print(line, flush=True)
    print(f"\n(pal demo took {time.perf_counter() - start:.1f} s; figures in {args.out})")
    return 0


def _babble(args: argparse.Namespace) -> int:
    from pal.sim.babbling import BabbleConfig, babble

    if args.mjcf and args.body:
        raise SystemExit("give either --body or --mjcf, not both")
    try:
        config = BabbleConfig(
            body=args.mjcf or args.body or "finger",
            joints=tuple(args.joint) if args.joint else None,
            actuators=tuple(args.actuator) if args.actuator else None,
            steps=args.steps,
            seed=args.seed,
            policy=args.policy,
            frame_skip=args.frame_skip,
            reset_every=args.reset_every,
            chunk_size=args.chunk_size,
        )
        start = time.perf_counter()
        dataset = babble(config, args.out, resume=args.resume, progress_bar=sys.stderr.isatty())
    except ValueError as err:  # bad names, bad MJCF, an occupied or corrupted directory
        raise SystemExit(str(err)) from None
    q = {j: dataset.columns[f"q.{j}"][:, 0] for j in dataset.joints}
    summary = {
        "out": str(args.out),
        "rows": len(dataset),
        "body": dataset.metadata["body"],
        "joints": dataset.joints,
        "q": {
            j: {"min": float(v.min()), "max": float(v.max()), "mean": float(v.mean()), "std": float(v.std())}
            for j, v in q.items()
        },
    }
    if args.json:
        print(json.dumps(summary, indent=2, sort_keys=True))
    else:
        print(
            f"{len(dataset)} transitions of {summary['body']!r} in {args.out} "
            f"({time.perf_counter() - start:.1f} s)"
        )
        for j, st in summary["q"].items():
            print(
                f"  q.{j}: [{st['min']:.3f}, {st['max']:.3f}] rad, mean {st['mean']:.3f}, std {st['std']:.3f}"
            )
    return 0


def _record(args: argparse.Namespace) -> int:
    from pal.perception import RecordedSequence
    from pal.sim.recording import RecordConfig, record

    if (Path(args.out) / "sequence.json").exists() and not args.overwrite:
        raise SystemExit(f"{args.out} already holds a sequence; pass --overwrite to replace it")
    try:
        config = RecordConfig(
            args.motion,
            seed=args.seed,
            fps=args.fps,
            width=args.width,
            height=args.height,
            depth_noise=args.depth_noise,
            rgb_noise=args.rgb_noise,
        )
        start = time.perf_counter()
        path = record(
            config, args.out, overwrite=args.overwrite, progress_bar=not args.json and sys.stderr.isatty()
        )
    except ValueError as err:  # unknown motion, bad sizes, an occupied directory
        raise SystemExit(str(err)) from None
    seq = RecordedSequence(path)
    summary = {
        "out": str(path),
        "motion": args.motion,
        "seed": args.seed,
        "frames": len(seq),
        "object": seq.metadata["object"],
        "gt_objects": list(seq.gt_objects),
        "backend": seq.metadata.get("backend"),
    }
    if args.json:
        print(json.dumps(summary, indent=2, sort_keys=True))
    else:
        print(
            f"{len(seq)} frames of {args.motion!r} (seed {args.seed}) in {path} ({time.perf_counter() - start:.1f} s)"
        )
    return 0


def _loop(args: argparse.Namespace) -> int:
    from pal.experiments.closed_loop import LoopConfig, run_loop

    goal = None
    if args.goal is not None:
        try:
            goal = tuple(float(v) for v in args.goal.split(","))
        except ValueError:
            raise SystemExit(f"--goal {args.goal!r}: expected X,Y in metres, e.g. --goal 0.05,0.15") from None
        if len(goal) != 2:
            raise SystemExit(f"--goal {args.goal!r}: expected two numbers X,Y in metres")
    if args.video is not None and not str(args.video).endswith(".mp4"):
        raise SystemExit(f"--video {args.video!r}: expected a path ending in .mp4")
    try:
        config = LoopConfig(steps=args.steps, babble=args.babble, goal=goal, seed=args.seed)
    except ValueError as err:
        raise SystemExit(str(err)) from None
    summary = run_loop(config, args.video, progress_bar=not args.json and sys.stderr.isatty())
    if args.json:
        print(json.dumps(summary, indent=2, sort_keys=True))
    else:
        modes = ", ".join(f"{k} {v}" for k, v in sorted(summary["modes"].items()))
        print(
            f"{summary['steps']} loop steps ({summary['babble_steps']} babbling, then {modes}) in "
            f"{summary['seconds']:.1f} s; "
            f"world model fitted on {summary['fit_rows']}"
        )
        lost = ", ".join(f"{o} {100 * f:.0f} %" for o, f in summary["lost_fraction"].items())
        print(f"objects lost by perception: {lost}")
        if summary["video"]:
            print(f"video: {summary['video']} ({summary['video_frames']} frames)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="pal", description="Causal perception-action learning toolkit.")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1)")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("demo", help="short end-to-end run: prints results, saves figures")
    p.add_argument("--out", default="pal-demo", help="directory for figures and JSON (default: pal-demo)")
    p.add_argument("--quick", action="store_true", help="smallest sizes (seconds)")
    p.set_defaults(func=_demo)

    for kind, help_text in (("bench", "run a benchmark"), ("experiment", "run an experiment")):
        p = sub.add_parser(kind, help=help_text)
        p.add_argument("name")
        p.add_argument("--json", action="store_true", help="print the result as JSON")
        p.add_argument("--out", default=None, help="directory for JSON, markdown and PNG figures")
        p.add_argument("--quick", action="store_true", help="small configuration")
        p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a config field")
        p.add_argument("--body", default=None, help="shipped body (finger, arm) where the run uses one")
        p.add_argument("--mjcf", default=None, metavar="PATH", help="any MJCF file instead of a shipped body")
        p.add_argument("--joint", action="append", metavar="NAME", help="joint to analyse (repeatable)")
        p.add_argument("--actuator", action="append", metavar="NAME", help="actuator to drive (repeatable)")
        p.set_defaults(func=lambda a, k=kind: _run_registered(k, a))

    p = sub.add_parser("babble", help="record motor-babbling transitions to a dataset directory")
    p.add_argument("--body", default=None, help="shipped body: finger (default) or arm")
    p.add_argument("--mjcf", default=None, metavar="PATH", help="any MJCF file instead of a shipped body")
    p.add_argument(
        "--joint", action="append", metavar="NAME", help="record this joint (repeatable; default all)"
    )
    p.add_argument(
        "--actuator", action="append", metavar="NAME", help="babble this actuator (repeatable; default all)"
    )
    p.add_argument("--steps", type=int, default=100_000, help="transitions (default 100000)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True, help="dataset directory")
    p.add_argument(
        "--policy", choices=["uniform", "ou"], default="uniform", help="babbling policy (default uniform)"
    )
    p.add_argument("--frame-skip", type=int, default=50, help="MuJoCo steps per transition (default 50)")
    p.add_argument("--reset-every", type=int, default=10_000, help="environment reset period (default 10000)")
    p.add_argument("--chunk-size", type=int, default=10_000, help="rows per chunk file (default 10000)")
    p.add_argument("--resume", action="store_true", help="continue an interrupted run in --out")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(func=_babble)

    p = sub.add_parser("record", help="record a scripted tabletop run as an RGB-D sequence with ground truth")
    p.add_argument("--motion", required=True, help="scripted motion of thesis Table 5.1, e.g. box-rotation")
    p.add_argument("--seed", type=int, default=0, help="run seed: path, speed, sensor noise (default 0)")
    p.add_argument("--out", required=True, help="sequence directory")
    p.add_argument("--fps", type=float, default=15.0, help="frames per second (default 15)")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument(
        "--depth-noise", type=float, default=0.002, help="depth noise std at 1 m, metres (default 0.002)"
    )
    p.add_argument("--rgb-noise", type=float, default=2.0, help="colour noise std, grey levels (default 2)")
    p.add_argument("--overwrite", action="store_true", help="replace a sequence already in --out")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(func=_record)

    p = sub.add_parser("loop", help="run the closed perception-action loop on the pushing world")
    p.add_argument("--steps", type=int, default=60, help="loop steps, babbling included (default 60)")
    p.add_argument(
        "--babble", type=int, default=None, help="babbling steps before the first fit (default half)"
    )
    p.add_argument(
        "--video", default=None, metavar="PATH", help="write an mp4 with the detections and targets"
    )
    p.add_argument("--goal", default=None, metavar="X,Y", help="push the box to this table position, m")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(func=_loop)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.threads < 1:
        raise SystemExit(f"--threads must be >= 1, got {args.threads}")
    _configure(args.verbose, args.threads)
    return int(args.func(args))


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
