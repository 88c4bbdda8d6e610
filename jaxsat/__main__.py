"""Command line: `python -m jaxsat demo` and `python -m jaxsat bench` (also installed as the
`jaxsat` console script)."""

from __future__ import annotations

import argparse
import importlib.util
import os
import pathlib
import sys
from collections.abc import Sequence

PEERS_SCRIPT = pathlib.Path(__file__).resolve().parent.parent / "benchmarks" / "peers.py"
"""The peers benchmark of a source checkout (found when jaxsat is installed editable)."""


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def build_parser() -> argparse.ArgumentParser:
    from jaxsat._demo import CASES

    script = os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else ""
    parser = argparse.ArgumentParser(
        prog="python -m jaxsat" if script in ("", "__main__.py", "-c") else script,
        description="jaxsat: batched, differentiable SAT collision detection in JAX.")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND")
    demo = commands.add_parser(
        "demo", help="random 2D/3D scenes: throughput, float32 accuracy and a picture",
        description="Build random pairs of convex shapes for each case, run "
                    "jax.jit(jax.vmap(jaxsat.penetration)) in float32 (timed after a warm-up) "
                    "and in float64, print pairs, collisions, float32 throughput and the "
                    "largest float32-vs-float64 differences, and draw a few pairs.")
    demo.add_argument("--pairs", type=_positive_int, default=4096,
                      help="pairs per case (default: %(default)s)")
    demo.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    demo.add_argument("--repeats", type=_positive_int, default=3,
                      help="timed float32 calls per case, best is reported (default: %(default)s)")
    demo.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES),
                      metavar="CASE", help=f"cases to run (default: all of {', '.join(CASES)})")
    demo.add_argument("--output", default="jaxsat_demo.png",
                      help="where to save the picture (default: %(default)s)")
    demo.add_argument("--no-plot", action="store_true", help="do not draw the picture")
    bench = commands.add_parser(
        "bench", help="jaxsat against its peers (MJX, MuJoCo, Coal, jax2d, pymunk, ...)",
        allow_abbrev=False,  # peers.py's --output must not be read as --output-dir
        description="Run the peers benchmark benchmarks/peers.py of this source checkout "
                    "(quick run by default) and print its table. Needs the peers: "
                    "pip install -e \".[bench]\"; a missing peer is skipped with a note. "
                    "Result files (PREFIX.json and PREFIX.md) go to --output-dir, not to the "
                    "checkout's benchmarks/results/: a full run always writes them, a quick "
                    "run only when --output-dir is given.",
        epilog="Any other argument is passed on to benchmarks/peers.py, for example "
               "--cases 3d-boxes --methods jaxsat mjx, --output PREFIX for files of your "
               "own naming (instead of --output-dir), --no-save to write no files, or --list "
               "to see which peers are installed; see python benchmarks/peers.py --help.")
    bench.add_argument("--full", action="store_true",
                       help="the full run (sizes 1e3-1e5, about 15 minutes on 2 cores) "
                            "instead of --quick")
    bench.add_argument("--output-dir", type=pathlib.Path, metavar="DIR",
                       help="write the results to DIR/peers-full.json and .md (--full) or "
                            "DIR/peers-quick.json and .md (created if missing; default: the "
                            "current directory for --full, no files for a quick run)")
    return parser


def _gives_output(extra: Sequence[str]) -> bool:
    return any(arg == "--output" or arg.startswith("--output=") for arg in extra)


def bench_argv(full: bool, extra: Sequence[str], output_dir: pathlib.Path | None) -> list[str]:
    """The arguments for benchmarks/peers.py: `extra`, --quick unless `full`, and --output
    OUTPUT_DIR/peers-full (default directory: the current one) or, for a quick run given an
    `output_dir`, OUTPUT_DIR/peers-quick, unless `extra` has its own --output. The prefix is
    absolute, so peers.py never falls back to its default in the checkout (benchmarks/results/),
    and a quick run without either writes nothing, as peers.py --quick does."""
    quick = not full or "--quick" in extra
    argv = list(extra) if full or "--quick" in extra else ["--quick", *extra]
    if _gives_output(extra):
        if output_dir is not None:
            raise ValueError("give --output-dir DIR or peers.py's --output PREFIX, not both")
        return argv  # the user's own prefix
    if output_dir is not None or not quick:
        directory = (output_dir or pathlib.Path.cwd()).expanduser().resolve()
        argv += ["--output", str(directory / ("peers-quick" if quick else "peers-full"))]
    return argv


def run_bench(full: bool, extra: Sequence[str], script: pathlib.Path | None = None,
              output_dir: pathlib.Path | None = None) -> int:
    """Run benchmarks/peers.py (default: PEERS_SCRIPT) in this process with
    bench_argv(full, extra, output_dir)."""
    script = PEERS_SCRIPT if script is None else script
    if not script.is_file():
        print(f"error: {script} not found. `python -m jaxsat bench` runs the peers benchmark "
              "of a jaxsat source checkout: clone the repository and install it editable with "
              "its peers (pip install -e \".[bench]\"), then run it from there.",
              file=sys.stderr)
        return 2
    spec = importlib.util.spec_from_file_location("jaxsat_bench_peers", script)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module.main(bench_argv(full, extra, output_dir))


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of `python -m jaxsat` and of the `jaxsat` console script."""
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra and args.command != "bench":
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    if args.command is None:
        parser.print_help()
        return 2
    if args.command == "demo":
        import jax

        # float64 reference runs need x64; float32 inputs still run in float32.
        jax.config.update("jax_enable_x64", True)
        from jaxsat._demo import run_demo

        run_demo(pairs=args.pairs, seed=args.seed, repeats=args.repeats, cases=args.cases,
                 output=None if args.no_plot else args.output)
        return 0
    if args.command == "bench":
        if args.output_dir is not None and _gives_output(extra):
            parser.error("bench: give --output-dir DIR or --output PREFIX, not both")
        return run_bench(args.full, extra, output_dir=args.output_dir)
    parser.error(f"unknown command {args.command!r}")  # unreachable: argparse checks choices
    return 2


if __name__ == "__main__":
    sys.exit(main())
