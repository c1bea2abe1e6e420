"""``mpirun -n N mscap run SCENE -o results.h5``: the multi-start design service."""

from __future__ import annotations

from mscap.cli.common import add_memory_option


def add_parser(sub) -> None:
    p = sub.add_parser("run", help="multi-start layout optimisation over MPI into one HDF5 file",
                       description="Run every start (k from the scene's k_min to k_max, starts_per_k "
                                   "each, Lloyd or random initial layouts) of the scene's multi-start; "
                                   "rank 0 schedules and writes, the other ranks optimise. Rerunning "
                                   "on an existing file completes only the missing runs.")
    p.add_argument("scene", help="scene file (jobs/*.toml)")
    p.add_argument("-o", "--output", metavar="RESULTS.h5", default="results.h5",
                   help="HDF5 results file (default: %(default)s)")
    p.add_argument("--k-min", type=int, metavar="K",
                   help="only starts with k >= K (default: the scene's [multistart] k_min)")
    p.add_argument("--k-max", type=int, metavar="K",
                   help="only starts with k <= K (default: the scene's [multistart] k_max)")
    p.add_argument("--seeds", metavar="A:B", help="only start indices A..B-1 within each k (the start from the "
                                                  "scene's layout, [multistart] scene_start, is index 999)")
    p.add_argument("--starts-per-k", type=int, metavar="N",
                   help="N starts per k instead of the scene's [multistart] starts_per_k")
    p.add_argument("--prune", metavar="STEP:ETA",
                   help="prune dominated starts from STEP accepted steps on, keeping the best 1/ETA at "
                        "each rung (0 disables; default: the scene's prune_first_step, prune_eta); "
                        "envelope:EVERY: every EVERY steps (default 5) stop a start that no finished "
                        "start's gain would lift to the best of its k (the safe rule)")
    p.add_argument("--keep-repeated-starts", action="store_true",
                   help="also run the Lloyd starts whose initial layout is an earlier start's of their k, "
                        "plate for plate (skipped by default: the same run bit for bit)")
    p.add_argument("--check-all-runs", action="store_true",
                   help="run the finer-mesh check on every run (default: only on runs not already beaten by a "
                        "finished run of their k, the only ones that can be a k's best)")
    p.add_argument("--calibrate-best", type=int, metavar="N",
                   help="in a scene with [calibration]: calibrate the best N runs of each k (with their initial "
                        "layouts and the scene's layout) at the end and choose the design and k on calibrated "
                        "read-back error; 0: choose by the objective alone (default: the scene's "
                        "[multistart] calibrate_best, 3)")
    p.add_argument("--max-iterations", type=int, help="L-BFGS iterations per level (default: the scene's)")
    p.add_argument("--force", action="store_true", help="start the file over even if it holds another scene")
    p.add_argument("--retry-failed", action="store_true", help="run the starts stored as failed again")
    p.add_argument("--heartbeat", type=float, default=20.0, metavar="SECONDS",
                   help="while starts run, a status line of every busy worker (run, step, metric, "
                        "elapsed) after this many seconds without a progress line; 0: none (default: %(default)s)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    add_memory_option(p)
    p.set_defaults(run=run)


def run(args) -> int:
    from mscap.cli.common import load_scene_for, progress_printer, rank_logging, start_mpi
    from mscap.service.multistart import run_multistart
    from mscap.errors import MscapError
    from mscap.service.selection import configurations, start_index
    from mscap.scene.loader import with_overrides

    comm = start_mpi().COMM_WORLD
    rank_logging(comm)  # before the scene is loaded: its warnings once, from rank 0
    scene = with_overrides(load_scene_for(args), args.starts_per_k, args.prune, args.keep_repeated_starts,
                           args.check_all_runs, args.calibrate_best)

    lo, hi = 0, None
    if args.seeds:
        a, _, b = args.seeds.partition(":")
        try:
            lo, hi = int(a or 0), (int(b) if b else None)
        except ValueError:
            raise MscapError(f"--seeds expects A:B (start indices, integers), got {args.seeds!r}") from None

    def keep(config) -> bool:
        i = start_index(config)
        return ((args.k_min is None or config.k >= args.k_min) and (args.k_max is None or config.k <= args.k_max)
                and i >= lo and (hi is None or i < hi))

    restricted = (args.k_min, args.k_max, args.seeds) != (None, None, None)
    if restricted and not any(keep(c) for c in configurations(scene)):  # a typo would otherwise do nothing, quietly
        ms = scene.multistart
        raise MscapError(f"{scene.path}: " + " ".join(f"{flag} {value}" for flag, value in (
            ("--k-min", args.k_min), ("--k-max", args.k_max), ("--seeds", args.seeds)) if value is not None)
            + f" selects none of its starts (k {ms.k_min}..{ms.k_max}, start indices 0:{ms.starts_per_k})")

    rank = comm.Get_rank()
    say = progress_printer(args.quiet or rank > 0)
    summary = run_multistart(scene, args.output, comm, force=args.force, retry_failed=args.retry_failed,
                             select_configs=keep if restricted else None, max_iterations=args.max_iterations,
                             progress=say, heartbeat_s=args.heartbeat)
    if rank == 0 and not args.quiet:
        print(f"{args.output}: {summary['runs_done']} runs this time ({summary['runs_failed']} failed)"
              + ("; stopped early" if summary["stopped"] else ""), flush=True)
        if summary.get("choice"):
            print(summary["choice"])
    return 0
