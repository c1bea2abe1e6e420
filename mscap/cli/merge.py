"""``mscap merge a.h5 b.h5 ... -o all.h5``: join results files of the same scene (e.g.
the tasks of a SLURM job array) and recompute the selection."""

from __future__ import annotations

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser("merge", help="join results files of the same scene",
                       description="Copy the runs of several results files of the same scene (same "
                                   "scene sha256) into one and recompute /selection. A run present "
                                   "in several inputs is taken from the first input where it succeeded "
                                   "(else the first where it appears).")
    p.add_argument("inputs", nargs="+", help="results files (.h5)")
    p.add_argument("-o", "--output", metavar="RESULTS.h5", required=True, help="merged results file")
    p.add_argument("--force", action="store_true", help="overwrite the output file")
    p.set_defaults(run=run)


def run(args) -> int:
    from mscap.service.merge import merge

    n = merge(args.inputs, args.output, force=args.force)
    print(f"wrote {args.output}: {n} runs from {len(args.inputs)} files")
    return 0
