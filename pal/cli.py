"""The ``pal`` command.

pal demo [--quick] [--out DIR]
pal list
pal experiment NAME [--quick] [--json] [--out DIR] [--set KEY=VALUE ...] [--body B | --mjcf PATH]
                    [--joint J] [--actuator A ...]
pal bench NAME [same options]
pal loop [--steps N] [--video out.mp4] [--babble B] [--goal X,Y] [--seed S] [--json] [--out DIR]
pal babble [--body finger|arm | --mjcf PATH] [--joint J ...] [--actuator A ...] --steps N --seed S
           --out DIR [--policy uniform|ou] [--resume] [--json]
pal record --motion MOTION --seed S --out DIR [--fps F] [--width W] [--height H] [--overwrite] [--json]

Every usage error (a bad flag, an unknown name, a setting of the wrong type, an unusable
``--out``) is one line on stderr and exit status 2, reported before any work starts.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn

__all__ = ["UsageError", "build_parser", "main"]

log = logging.getLogger("pal")

#: ``pal experiment|bench`` body flags -> field of the config's body choice.
BODY_FLAGS = {"body": "body", "mjcf": "mjcf", "joint": "joint", "actuator": "actuator"}


class UsageError(Exception):
    """A command line that cannot be run; printed as one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors."""

    def error(self, message: str) -> NoReturn:
        raise UsageError(f"{self.prog}: {message}")


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
    for noisy in ("matplotlib", "PIL", "OpenGL", "numexpr", "h5py", "jax"):
        logging.getLogger(noisy).setLevel(logging.WARNING)


def _output_dir(out: str | None) -> Path | None:
    from pal.experiments.runner import OutputError, check_output_dir

    if out is None:
        return None
    try:
        return check_output_dir(out)
    except OutputError as err:
        raise UsageError(str(err)) from None


def _body_fields(entry: Any, args: argparse.Namespace) -> dict[str, Any]:
    from pal.experiments import configs
    from pal.experiments.wm_data import BodyChoice

    given = {flag: getattr(args, flag, None) for flag in BODY_FLAGS}
    given = {k: (tuple(v) if isinstance(v, list) else v) for k, v in given.items() if v is not None}
    if "joint" in given:
        if len(given["joint"]) != 1:
            raise UsageError(
                f"--joint given {len(given['joint'])} times {list(given['joint'])}; name the one joint to analyse"
            )
        given["joint"] = given["joint"][0]
    if not given:
        return {}
    paths = configs.find(entry.default(), BodyChoice)
    if not paths:
        flags = ", ".join(f"--{k}" for k in given)
        raise UsageError(f"{flags}: pal {entry.kind} {entry.name} has no body setting")
    prefix = f"{paths[0]}." if paths[0] else ""
    return {f"{prefix}{BODY_FLAGS[k]}": v for k, v in given.items()}


def _run_entry(kind: str, name: str, args: argparse.Namespace, fields: dict[str, Any] | None = None) -> int:
    from pal.experiments import registry, render
    from pal.experiments.runner import configure, execute

    try:
        entry = registry.get(kind, name)
    except ValueError as err:
        raise UsageError(str(err)) from None
    try:
        config = configure(
            entry,
            quick=getattr(args, "quick", False),
            sets=getattr(args, "set", None) or (),
            fields={**_body_fields(entry, args), **(fields or {})},
        )
    except ValueError as err:  # unknown setting, wrong type, or refused by the config's checks
        raise UsageError(f"pal {kind} {name}: {err}") from None
    out = _output_dir(args.out)
    record = execute(entry, config, progress_bar=not args.json and sys.stderr.isatty())
    if out is not None:
        paths = render.write(record, out)
        log.info("wrote %s", ", ".join(str(p) for p in paths.values()))
    if args.json:
        print(json.dumps(render.document(record), indent=2, sort_keys=True, allow_nan=False))
    else:
        print(render.markdown(record))
    return 0


def _demo(args: argparse.Namespace) -> int:
    from pal.experiments import demo

    out = _output_dir(args.out)
    start = time.perf_counter()
    for text in demo.run(out, quick=args.quick, progress_bar=sys.stderr.isatty()):
        print(text, flush=True)
    print(f"\n(pal demo took {time.perf_counter() - start:.1f} s; reports and figures in {out})")
    return 0


def _list(args: argparse.Namespace) -> int:
    from pal.experiments import registry

    for entry in registry.entries():
        print(f"pal {entry.kind:<10} {entry.name:<16} {entry.summary}")
    return 0


def _loop(args: argparse.Namespace) -> int:
    fields: dict[str, Any] = {"steps": args.steps, "seed": args.seed}
    if args.babble is not None:
        fields["babble"] = args.babble
    if args.goal is not None:
        try:
            goal = tuple(float(v) for v in args.goal.split(","))
        except ValueError:
            raise UsageError(f"--goal {args.goal!r}: expected X,Y in metres, e.g. --goal 0.05,0.15") from None
        if len(goal) != 2:
            raise UsageError(f"--goal {args.goal!r}: expected two numbers X,Y in metres")
        fields["goal"] = goal
    if args.video is not None:
        if not str(args.video).endswith(".mp4"):
            raise UsageError(f"--video {args.video!r}: expected a path ending in .mp4")
        parent = Path(args.video).resolve().parent
        _output_dir(str(parent))
        fields["video"] = str(args.video)
    return _run_entry("experiment", "loop", args, fields)


def _babble(args: argparse.Namespace) -> int:
    from pal.sim.babbling import BabbleConfig, babble

    if args.mjcf and args.body:
        raise UsageError("give either --body or --mjcf, not both")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {args.out!r} is a file, expected a dataset directory")
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
    except ValueError as err:  # bad sizes, names or MJCF
        raise UsageError(f"pal babble: {err}") from None
    _output_dir(args.out)
    start = time.perf_counter()
    try:
        dataset = babble(config, args.out, resume=args.resume, progress_bar=sys.stderr.isatty())
    except ValueError as err:  # bad names, an occupied, locked or corrupted directory
        raise UsageError(f"pal babble: {err}") from None
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
            f"{len(dataset)} transitions of {summary['body']!r} in {args.out} ({time.perf_counter() - start:.1f} s)"
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
        raise UsageError(f"{args.out} already holds a sequence; pass --overwrite to replace it")
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
    except ValueError as err:  # unknown motion, bad sizes
        raise UsageError(f"pal record: {err}") from None
    _output_dir(args.out)
    start = time.perf_counter()
    try:
        path = record(
            config, args.out, overwrite=args.overwrite, progress_bar=not args.json and sys.stderr.isatty()
        )
    except ValueError as err:  # an occupied directory
        raise UsageError(f"pal record: {err}") from None
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


def _add_run_flags(p: argparse.ArgumentParser, *, body: bool = True) -> None:
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument("--out", default=None, help="directory for JSON, markdown and PNG figures (checked first)")
    if body:
        p.add_argument("--quick", action="store_true", help="small configuration")
        p.add_argument(
            "--set",
            action="append",
            metavar="KEY=VALUE",
            help="override a setting, e.g. protocol.fit.epochs=40",
        )
        p.add_argument("--body", default=None, help="shipped body (finger, arm) where the run uses one")
        p.add_argument("--mjcf", default=None, metavar="PATH", help="any MJCF file instead of a shipped body")
        p.add_argument("--joint", action="append", metavar="NAME", help="joint to analyse")
        p.add_argument("--actuator", action="append", metavar="NAME", help="actuator to drive (repeatable)")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``pal``."""
    parser = _Parser(prog="pal", description="Causal perception-action learning toolkit.")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging and tracebacks")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1)")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    p = sub.add_parser("demo", help="short end-to-end run: prints reports, saves figures")
    p.add_argument("--out", default="pal-demo", help="directory for reports and figures (default: pal-demo)")
    p.add_argument("--quick", action="store_true", help="smallest sizes")
    p.set_defaults(func=_demo)

    p = sub.add_parser("list", help="list the registered experiments and benchmarks")
    p.set_defaults(func=_list)

    for kind, help_text in (("bench", "run a benchmark"), ("experiment", "run an experiment")):
        p = sub.add_parser(kind, help=help_text)
        p.add_argument("name")
        _add_run_flags(p)
        p.set_defaults(func=lambda a, k=kind: _run_entry(k, a.name, a))

    p = sub.add_parser("loop", help="the closed perception-action loop (= pal experiment loop)")
    p.add_argument("--steps", type=int, default=60, help="loop steps, babbling included (default 60)")
    p.add_argument(
        "--babble", type=int, default=None, help="babbling steps before the first fit (default half)"
    )
    p.add_argument(
        "--video", default=None, metavar="PATH", help="write an mp4 with the detections and targets"
    )
    p.add_argument("--goal", default=None, metavar="X,Y", help="push the box to this table position, m")
    p.add_argument("--seed", type=int, default=0)
    _add_run_flags(p, body=False)
    p.set_defaults(func=_loop)

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
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``pal``; returns the exit status (2 for usage errors, printed as one line on stderr)."""
    verbose = False
    try:
        args = build_parser().parse_args(argv)
        verbose = args.verbose
        if args.threads < 1:
            raise UsageError(f"--threads must be >= 1, got {args.threads}")
        _configure(args.verbose, args.threads)
        return int(args.func(args))
    except UsageError as err:
        print(f"pal: error: {err}" if not str(err).startswith("pal") else f"{err}", file=sys.stderr)
        return 2
    except (ValueError, OSError) as err:  # bad input found while running (e.g. a body's names)
        if verbose:
            raise
        print(f"pal: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
