"""python -m boxpose_ray: `make scenes` and `boxpose search` as Ray tasks (docs/scale-out.md).

    python -m boxpose_ray scenes --recipe clutter --dataset DIR --num-shards 8 --address auto
    python -m boxpose_ray search --address auto -- single_box --samples 2000 --out RUN

Killing the driver, a worker or the cluster loses at most the tasks in flight: run the same
command again and it resumes from what the output folder holds.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tqdm import tqdm


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m boxpose_ray",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__.split("\n\n", 1)[1],
    )
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        "--address",
        default="local",
        help="`local` (default: a private Ray instance on this machine, loopback only), `auto` "
        "(the cluster this machine joined with `ray start`) or HOST:PORT of a head node",
    )
    common.add_argument(
        "--cpus-per-task",
        type=float,
        default=1,
        help="CPUs Ray reserves per task; also each task's Cycles threads (default 1)",
    )
    common.add_argument(
        "--gpus-per-task",
        type=float,
        default=0,
        help="GPUs Ray reserves per task (default 0; for a search with --backend cuda or wgpu)",
    )
    commands = ap.add_subparsers(dest="command", required=True)
    scenes = commands.add_parser(
        "scenes",
        parents=[common],
        help="generate a dataset, one task per shard (scripts/make_scenes.py)",
        description="Generate a dataset from a recipe with one Ray task per shard, then validate "
        "it with `boxpose inspect`. The same command resumes an interrupted run.",
    )
    scenes.add_argument("--recipe", required=True, help="recipe name or TOML path")
    scenes.add_argument(
        "--dataset", type=Path, required=True, help="output folder, seen by every node"
    )
    scenes.add_argument("--num-shards", type=int, required=True, help="shards = tasks")
    scenes.add_argument("--num-scenes", type=int, help="override the recipe's num_scenes")
    search = commands.add_parser(
        "search",
        parents=[common],
        help="a counterexample search, one task per batch (boxpose search)",
        description="Run `boxpose search ARGS` with one Ray task per batch; the cross-entropy "
        "proposal moves at each iteration's barrier. Put the search's own options after `--`; "
        "--out must name a folder every node sees.",
    )
    search.add_argument("search_args", nargs=argparse.REMAINDER, help="boxpose search's options")
    args = ap.parse_args(argv)
    if not args.cpus_per_task > 0 or not args.gpus_per_task >= 0:
        ap.error("--cpus-per-task must be positive and --gpus-per-task not negative")

    import ray

    import boxpose_ray

    bars: list[tqdm] = []  # drawn from the first progress report on, not before errors

    def progress(what: str, done: int, total: int) -> None:
        if not bars or bars[-1].desc != f"{what}: ":  # a new iteration: its own bar and rate
            if bars:
                bars[-1].close()
            unit = "shard" if what == "shards" else "sample"
            bars.append(tqdm(desc=what, total=total, unit=unit, dynamic_ncols=True))
        bars[-1].update(done - bars[-1].n)

    def close() -> None:
        for bar in bars:
            bar.close()

    search_args = getattr(args, "search_args", [])
    search_args = search_args[1:] if search_args[:1] == ["--"] else search_args
    resources = boxpose_ray.TaskResources(args.cpus_per_task, args.gpus_per_task)
    try:
        if args.command == "search":
            boxpose_ray.check_search_args(search_args)
        boxpose_ray.connect(args.address)
        if args.command == "scenes":
            boxpose_ray.generate_scenes(
                args.recipe,
                args.dataset,
                args.num_shards,
                num_scenes=args.num_scenes,
                resources=resources,
                progress=progress,
            )
            close()
            print(f"dataset: {args.dataset.resolve()}")
        else:
            estimate = boxpose_ray.search(search_args, resources=resources, progress=progress)
            close()
            print(estimate, end="")
    except (boxpose_ray.StageFailed, boxpose_ray.StageInterrupted, ray.exceptions.RayError) as e:
        close()
        # a task's error arrives wrapped with its remote traceback: the stage's message is the news
        print(f"error: {getattr(e, 'cause', None) or e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        close()
        print("stopped: run the same command again to resume", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
