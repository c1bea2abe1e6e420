"""The multi-start service: many optimisation starts farmed out over MPI, one HDF5 file.

Rank 0 is the master: it opens the store (:mod:`mscap.service.store`), lists the start
configurations the file does not hold yet (:func:`mscap.service.selection.configurations`,
less the Lloyd starts that repeat an earlier start's layout,
:func:`~mscap.service.selection.repeated_starts`) and hands them out one at a time; every
other rank is a worker that runs one start (:func:`run_start`) on ``PETSc.COMM_SELF`` and
sends back a :class:`~mscap.service.store.RunRecord`. Scheduling is dynamic — a worker
gets the next configuration as soon as it returns one — and only the master writes:
each run is stored and ``fsync``-ed, then ``/selection`` is rewritten, then the run is
announced, so a killed job loses at most the runs in flight. A write the disk cannot
take (:class:`~mscap.errors.StoreFullError`) or any other error of the master ends every
rank of the job (:func:`mscap.farm.run`); the file keeps every stored run. With one
rank (no ``mpirun``) the master runs every start itself.

A start's result depends only on the scene and its (k, seed, init): never on the rank,
the number of ranks or the order in which runs finish — unless the scene prunes
(``[multistart] prune_first_step``, :mod:`mscap.service.pruning`): then each start asks the
master at its rungs whether it is still among the best of its k (or, with ``prune_rule =
"envelope"``, whether any path seen so far would lift it to the best of its k), and a
dominated one stops and is stored as pruned. A finished start asks the master once more,
before its finer-mesh check: a run that a finished run of its k already beats can never
be the best of its k, the only runs whose check the selection reads, so it is stored
unchecked (``[multistart] check_all_runs = true`` checks every run). Which runs are checked
depends on the order in which runs finish; their results do not. A k's best stored
unchecked (a stop between its run and its check, or a failed check) is checked when the
job runs again. A start that raises is stored as failed
with its error text; the others go on. While starts run, the master
prints a status line of its busy workers after :data:`~mscap.service.heartbeat.HEARTBEAT_S`
seconds without a progress line (:mod:`mscap.service.heartbeat`). SIGTERM (what SLURM sends
at the time limit), SIGUSR1 and Ctrl-C stop the master from handing out more work; busy
workers drop their start at its next step (it runs again on resume), the master records
what finished and writes the selection (:func:`mscap.farm.run`).

In a scene with ``[calibration]`` the starts are followed by a calibration of the best
designs, farmed the same way, and the design and k are chosen on calibrated read-back error
(:mod:`mscap.service.calibrated`); storing a new run drops that calibration until the job's
end makes it again.
"""

from __future__ import annotations

import logging
import math
import socket
import time
import traceback
from collections import Counter
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Callable

from mscap.fem.simulate import release_freed_memory
from mscap.mesh.budget import check_meshes
from mscap.errors import MscapError
from mscap.service import checkpoints
from mscap.service.accuracy import Equilibria, estimate_error, finer
from mscap.design.readback import read_back_estimate
from mscap import farm
from mscap.service import calibrated
from mscap.service.forecast import Forecast, duration
from mscap.service.heartbeat import HEARTBEAT_S, Heartbeat, Progress
from mscap.service.pruning import Envelope, PruneRule, Rungs, Verdict, history_values, prune_rule, score, \
    score_kind
from mscap.service.selection import StartConfig, configurations, rank_key, repeated_starts, run_score, select
from mscap.service.store import drop_calibration, failed_record, finished_ids, open_store, read_calibration, \
    read_run, record_from_result, run_summaries, run_summary, write_run, write_selection
from mscap.service.usage import Meter

if TYPE_CHECKING:
    from mscap.scene.settings import Scene

__all__ = ["run_start", "run_check", "run_multistart", "stored_table", "Finished", "CheckTask", "beaten_by",
           "on_hosts", "choice_text"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Finished:
    """A finished start's question before its finer-mesh check: is it already beaten?"""

    id: str
    k: int
    metric: float
    bound_mm: float


def beaten_by(question: Finished, runs) -> str | None:
    """The id of a stored run of the same k that :func:`~mscap.service.selection.select`
    ranks above ``question``'s run whatever else finishes (ok, not pruned;
    :func:`~mscap.service.selection.rank_key`: a smaller read-back bound when the runs have
    one, else a larger min L1 distance; ties to the smaller id), or ``None``: then the run
    may still be the best of its k and needs its check."""
    by_bound = math.isfinite(question.bound_mm) and question.bound_mm > 0
    mine = rank_key(question, by_bound)
    better = [r for r in runs if r.k == question.k and r.ok and not r.pruned and r.id != question.id
              and math.isfinite(run_score(r, by_bound)) and rank_key(r, by_bound) < mine]
    return min(better, key=lambda r: rank_key(r, by_bound)).id if better else None


def run_start(scene: Scene, config: StartConfig, rank: int = 0, max_iterations: int | None = None,
              ask: Callable[[tuple], Verdict] | None = None):
    """Run one start and return its :class:`~mscap.service.store.RunRecord` (failed, with the
    error text, if anything in it raises). With a pruning rule in the scene, ``ask`` gets
    a :class:`~mscap.service.heartbeat.Progress` after every accepted step (the master's
    heartbeat) and answers at each pruning rung (:func:`mscap.service.pruning.score`) with a
    :class:`~mscap.service.pruning.Verdict`; a start told to stop is stored as pruned. When
    the master is stopping, ``ask`` raises :class:`~mscap.farm.Abandoned`: the start
    returns its last optimiser state (:class:`~mscap.service.checkpoints.Interrupted`), which
    the master keeps for a rerun to continue, or, before its first state, lets the
    ``Abandoned`` pass: the start is not recorded and runs again on resume. Every
    ``[multistart] checkpoint_minutes`` the state goes to the master
    (:class:`~mscap.service.checkpoints.Checkpoint`); ``config.resume``, a stored state, is
    where the start goes on from."""
    from mscap.design.optimizer import optimize
    from mscap.design.state import resumable

    release_freed_memory()  # what the previous start on this worker freed
    start, meter = time.perf_counter(), Meter()
    layout = None
    keeper = _Keeper(config.id, ask, 60.0 * scene.multistart.checkpoint_minutes) \
        if ask is not None and resumable(scene) else None
    try:
        layout, design, resume = _start_or_resume(scene, config)
        sheet = design.sheet  # the start's layout, its meshes sized for it (sheet_for)
        designed = design.designed  # the design poses and their family (mscap.design.readback.design_poses)
        rule, kind, verdicts = PruneRule.from_settings(scene.multistart), score_kind(scene), []

        def checkpoint(row) -> bool:
            rung = rule.enabled and rule.is_rung(row.iteration)
            verdict = ask(Progress(config.id, config.k, row.iteration, float(row.min_l1_pF),
                                   float(score(kind, row.J, row.terms["d"], row.min_l1_pF)), rung, kind))
            if not rung:
                return True
            verdicts.append(verdict)
            return verdict.keep

        handed = [design]
        del design  # optimize() holds the only reference: the first remesh frees the design
        try:
            result = optimize(handed.pop(), max_iterations=max_iterations,
                              checkpoint=checkpoint if ask is not None else None, keep=keeper, resume=resume)
        except farm.Abandoned:
            if keeper is None or keeper.latest is None:
                raise
            return checkpoints.Interrupted(config.id, keeper.latest)
        earlier = 0.0 if resume is None else resume.time_s  # a resumed start's earlier sessions
        record = replace(record_from_result(config.k, config.seed, config.init, layout, result, designed.poses,
                                            time.perf_counter() - start + earlier, rank), cpu_s=meter.cpu_s)
        if result.reason == "pruned":
            record = replace(record, status="pruned", reason=verdicts[-1].reason(rule))
        bound = read_back_estimate(scene, designed)
        if bound is not None:
            record = replace(record, bound_mm=bound.value(record.final_capacitance_pF),
                             initial_bound_mm=bound.value(record.initial_capacitance_pF))
        final = result.layout
        equilibria = Equilibria.of(result.evaluation) if scene.multistart.error_estimate else None
        share = result.evaluation.offset_pF  # the leads', routed during the optimisation
        result.design.close()
        del result  # the finer mesh's check below should not add to the design's memory
        release_freed_memory()
    except Exception as exc:  # a failed start is a result, not a crash of the job
        log.debug("start %s failed:\n%s", config.id, traceback.format_exc())
        return replace(failed_record(config.k, config.seed, config.init, f"{type(exc).__name__}: {exc}",
                                     time.perf_counter() - start, rank, layout, getattr(exc, "history", ())),
                       cpu_s=meter.cpu_s, peak_rss_mb=meter.peak_rss_mb)
    if scene.multistart.error_estimate and not record.pruned:
        record = _with_check(scene, replace(sheet, layout=final), record, equilibria, bound, ask, share,
                             designed.poses)
    return replace(record, peak_rss_mb=meter.peak_rss_mb)  # the start's and its check's


class _Keeper:
    """The optimiser's ``keep``: the state at the top of each iteration, sent to the master
    (``ask``) when ``interval_s`` has passed since the last one sent (0: never)."""

    def __init__(self, run_id: str, ask, interval_s: float):
        self.run_id, self.ask, self.interval_s = run_id, ask, interval_s
        self.latest, self.sent = None, time.monotonic()

    def __call__(self, state) -> None:
        self.latest = state()
        if self.interval_s > 0 and time.monotonic() - self.sent >= self.interval_s:
            self.ask(checkpoints.Checkpoint(self.run_id, self.latest))
            self.sent = time.monotonic()


def _start_or_resume(scene: Scene, config: StartConfig):
    """``(initial layout, design, state)`` of a start: its own first design
    (:func:`~mscap.design.starts.start_design`, state ``None``), or, with ``config.resume``,
    the design of that state (:func:`~mscap.design.optimizer.resumed_design`; one that
    cannot be rebuilt is said and the start begins afresh)."""
    from mscap.design.optimizer import resumed_design
    from mscap.design.starts import start_design, start_layout
    from mscap.scene.sizing import sheet_for

    if config.resume is not None:
        try:
            layout = start_layout(scene, config.k, config.seed, config.init)
            design = resumed_design(scene, sheet_for(scene, layout), config.resume)
            return layout, design, config.resume
        except Exception as exc:  # noqa: BLE001 — a state that does not fit: start over
            log.warning("start %s: its checkpoint cannot be resumed (%s: %s); it runs from its beginning",
                        config.id, type(exc).__name__, str(exc)[:200])
    layout, design = start_design(scene, config.k, config.seed, config.init)
    return layout, design, None


def _with_check(scene: Scene, sheet, record, equilibria, bound, ask, share=None, poses=None):
    """``record`` with its finer-mesh check of ``sheet`` (the start's sizes, its final
    layout; over its design ``poses``), unless
    the master says a finished run of its k beats it; a failed check leaves NaN. ``share``:
    the leads' share in the record's capacitances (routed during the optimisation), held
    on the finer mesh too, so that the check measures the plates' discretisation alone."""
    if ask is not None and not scene.multistart.check_all_runs:
        try:
            beaten = ask(Finished(record.id, record.k, record.metric, record.bound_mm))
        except farm.Abandoned:  # the job is stopping: keep the finished run, unchecked
            log.warning("start %s: stored without its finer-mesh check (the job is stopping)", record.id)
            return record
        if beaten is not None:
            log.info("start %s: no finer-mesh check, %s of its k is better", record.id, beaten)
            return record
    cpu = time.process_time()
    try:
        plates = record.final_capacitance_pF if share is None else record.final_capacitance_pF - share
        check = estimate_error(scene, sheet, plates, equilibria, poses)
    except Exception as exc:  # the run stands; only its accuracy is unknown
        log.warning("start %s: the finer-mesh error estimate failed (%s: %s); stored as NaN",
                    record.id, type(exc).__name__, exc)
        return replace(record, error_estimate_cpu_s=time.process_time() - cpu)
    # The bound of the same design on the finer mesh: the read-back scenes' k is checked on it
    # as the others' is on the finer min L1 (mscap.service.selection).
    finer = check.capacitance_pF if share is None else check.capacitance_pF + share
    return replace(record, finer_capacitance_pF=finer, error_estimate_wall_s=check.wall_s,
                   error_estimate_cpu_s=time.process_time() - cpu,
                   finer_bound_mm=math.nan if bound is None else bound.value(finer))


@dataclass(frozen=True)
class CheckTask:
    """A stored run whose finer-mesh check the selection needs: a k's best left unchecked
    (its job stopped between the run and its check, or the check failed)."""

    record: object  # a RunRecord

    @property
    def id(self) -> str:
        return self.record.id


def run_check(scene: Scene, record, ask: Callable | None = None):
    """``record`` (a stored run) with the finer-mesh check its start would have ended with,
    from a cold start on the finer mesh (the run's equilibria are gone). The master is
    asked first, as a start asks: a run beaten meanwhile stays unchecked."""
    from mscap.design.readback import design_poses
    from mscap.design.starts import start_layout
    from mscap.geometry.layout import Layout
    from mscap.scene.sizing import sheet_for

    release_freed_memory()
    meter = Meter()
    sheet = sheet_for(scene, start_layout(scene, record.k, record.seed, record.init))  # the start's sizes
    designed = design_poses(scene)
    share = None  # the leads' share in the stored capacitances is not stored: routed again
    if scene.fabrication.route_during_optimisation:
        from mscap.errors import FabricationError
        from mscap.fabrication.during import wiring_offset

        try:
            share = wiring_offset(scene, sheet, record.final_outlines, poses=designed.poses).offset_pF
        except FabricationError as exc:
            log.warning("start %s: its design no longer routes (%s); checked as plates alone", record.id, exc)
    checked = _with_check(scene, replace(sheet, layout=Layout(tuple(record.final_outlines))), record, None,
                          read_back_estimate(scene, designed), ask, share, designed.poses)
    # The larger of the run's peak (an earlier session's; NaN if not stored) and the check's here.
    peak = meter.peak_rss_mb if not record.peak_rss_mb > meter.peak_rss_mb else record.peak_rss_mb
    return replace(checked, peak_rss_mb=peak)


def run_multistart(scene: Scene, path: str, comm=None, force: bool = False, retry_failed: bool = False,
                   select_configs: Callable[[StartConfig], bool] | None = None,
                   max_iterations: int | None = None,
                   progress: Callable[[str], None] | None = None,
                   heartbeat_s: float = HEARTBEAT_S, calibrate: bool = True) -> dict | None:
    """Run every start of ``scene`` not yet in the file ``path``.

    Parameters
    ----------
    comm
        An mpi4py communicator (default ``MPI.COMM_WORLD``); rank 0 is the master.
    force
        Start the file over even if it holds another scene's runs.
    retry_failed
        Run the starts stored as failed again (their groups are replaced).
    select_configs
        Keep only the configurations for which this returns True (k range, seed range).
    max_iterations
        Override the scene's ``[optimizer] max_iterations`` (tests, quick runs).
    progress
        Called by the master with one line per finished run, and with a status line of
        the busy workers after ``heartbeat_s`` seconds without one (0: never;
        :mod:`mscap.service.heartbeat`).
    calibrate
        In a scene with ``[calibration]``, end by calibrating the best designs and choosing
        on calibrated read-back error (:mod:`mscap.service.calibrated`; not with
        ``select_configs``).

    Returns the master's summary ``{"runs_done", "runs_failed", "stopped"}`` on rank 0,
    ``None`` on workers.
    """
    if comm is None:
        from mpi4py import MPI

        comm = MPI.COMM_WORLD
    rank = comm.Get_rank()
    hosts = comm.gather(socket.gethostname(), root=0)  # where the workers run (said by the master)

    def master(execute, stop) -> dict:
        return _master(scene, path, comm.Get_size(), force, retry_failed, select_configs, execute, stop,
                       Heartbeat(progress, heartbeat_s), hosts[1:])

    def work(ask):
        return lambda task: run_check(scene, task.record, ask) if isinstance(task, CheckTask) else \
            run_start(scene, task, rank, max_iterations, ask)

    summary = farm.run(comm, work, master,
                       "stopped: the finished runs are stored; rerun the same command to complete the rest",
                       progress or (lambda m: None))
    # A job restricted to some starts (a part of an array) leaves the calibration to the
    # merged file's `mscap run`: its own candidates are not the whole multi-start's.
    if not (calibrate and calibrated.wanted(scene) and select_configs is None):
        return summary
    if comm.bcast(None if summary is None else summary["stopped"], root=0):
        return summary
    selection = calibrated.calibrate_selection(scene, path, comm, progress)
    if selection is not None:  # rank 0
        summary["choice"] = choice_text(selection)
    return summary


def on_hosts(hosts) -> str:
    """The workers' hosts for the master's first line, ``" on 2 hosts (node1: 3, node2: 4)"``,
    when they run on more than one host; else ``""``."""
    counts = Counter(hosts)
    if len(counts) < 2:
        return ""
    return f" on {len(counts)} hosts ({', '.join(f'{h}: {n}' for h, n in sorted(counts.items()))})"


def choice_text(selection, left: int = 0) -> str | None:
    """The run's closing lines on its choice: the chosen k and design, what the choice rests
    on (:meth:`~mscap.service.selection.Selection.verdict`), and advice when the plateau is
    not confirmed; ``None`` when nothing was chosen. ``left``: the tasks a stopped job left
    to do; the choice is then the stored runs' so far, and says so."""
    if selection.chosen_k is None:
        return None
    design = selection.chosen_design
    which = f"design {design}" if design != selection.chosen_run else f"run {design}"
    so_far = (f"so far ({left} task{'s' * (left != 1)} left: the job stopped; rerun the same command to complete "
              "them, which may choose otherwise): ") if left else ""
    return (f"{so_far}chosen k = {selection.chosen_k} ({which}); {selection.verdict()}"
            + (f"\n{selection.advice()}" if selection.advice() else ""))


def _master(scene: Scene, path, size, force, retry_failed, select_configs, execute, stop,
            heartbeat: Heartbeat, hosts: list[str] = ()) -> dict:
    say = heartbeat.say
    # Every start meshes the scene and, when checked, its finer mesh: refuse a mesh beyond
    # memory now, not at the end of the first start.
    check_meshes(scene.sheet, scene.elastic, scene.poses)
    if scene.multistart.error_estimate:
        check_meshes(*finer(scene.sheet, scene.elastic), scene.poses)
    rule, kind = prune_rule(scene), score_kind(scene)
    store = open_store(path, scene, mpi_size=size, force=force)
    if force:
        checkpoints.drop_all(path)
    done = failed = 0
    ms = scene.multistart
    summaries = {}

    def selection():
        return select(list(summaries.values()), ms.plateau_tol, range(ms.k_min, ms.k_max + 1),
                      read_calibration(store))
    try:
        summaries.update((summary.id, summary) for summary in run_summaries(store))
        finished = finished_ids(store, failed=not retry_failed)
        configs = configurations(scene)
        repeats = repeated_starts(scene, configs) if ms.skip_repeated_starts else {}
        wanted = [c for c in configs if c.id not in finished and (select_configs is None or select_configs(c))]
        todo = [c for c in wanted if c.id not in repeats]
        skipped = [f"{c.id} (= {repeats[c.id]})" for c in wanted if c.id in repeats]
        # Longest first: a start's cost grows with k, and handing out the big ones first
        # leaves the short ones to fill the tail (jobs/quick.toml on 2 workers: busy
        # fraction 0.88 → 0.94, docs/performance.md §4). Results do not depend on the order.
        todo.sort(key=lambda c: -c.k)
        todo, resumed = _with_checkpoints(path, todo, say)
        # A k's best stored without its check (a stop between the run and its check, or a
        # failed check): checked after the starts, if still the best (run_check asks).
        selected = {c.id for c in configs if select_configs is None or select_configs(c)}
        pending = [] if not ms.error_estimate else \
            [CheckTask(read_run(store, row.best_run)) for row in selection().per_k
             if row.best_run in selected and math.isnan(summaries[row.best_run].finer_metric)]
        todo = todo + pending
        total, forecast = len(todo), Forecast(todo, max(size - 1, 1), rule)
        for summary in summaries.values():  # a resumed job knows its stored runs' costs
            if summary.ok and summary.id not in forecast.left:
                forecast.finished(summary.id, summary.wall_s, summary.pruned, kind=("start", summary.k),
                                  init=summary.id.rsplit("_", 1)[-1])
        say(f"{path}: {len(finished)} runs already stored, {total} to do on {max(size - 1, 1)} "
            f"worker{'s' if size > 2 else ''}{on_hosts(hosts)}")
        if pending:
            say(f"{len(pending)} of them the finer-mesh check{'s' if len(pending) > 1 else ''} of "
                f"{', '.join(t.id for t in pending)}: the best of {'their' if len(pending) > 1 else 'its'} k, "
                f"stored unchecked")
        if resumed:
            say(f"{len(resumed)} start{'s' if len(resumed) > 1 else ''} continue{'' if len(resumed) > 1 else 's'} "
                f"from {'their' if len(resumed) > 1 else 'its'} stored state: {', '.join(resumed)}")
        if skipped:
            say(f"skipped {len(skipped)} Lloyd start{'s' if len(skipped) > 1 else ''} whose initial layout repeats "
                f"an earlier start of its k: {', '.join(skipped)}")
        rungs = stored_table(store, rule, kind)

        def keep(state: checkpoints.Checkpoint | checkpoints.Interrupted) -> str | None:
            """Store a start's state; why it could not be, or ``None`` (a start not kept runs
            again from its beginning)."""
            try:
                checkpoints.save(path, state.id, state.state)
            except (OSError, ValueError, MscapError) as exc:
                return str(exc)
            return None

        def record(rec) -> None:
            nonlocal done, failed
            if isinstance(rec, checkpoints.Interrupted):  # the job is stopping: a rerun continues it
                why = keep(rec)
                say(f"{rec.id}: stopped at step {rec.state.iteration} (level {rec.state.level}); its state is "
                    + (f"kept in {checkpoints.directory(path)}: a rerun continues it" if why is None else
                       f"not kept ({why}): a rerun runs it from its beginning"))
                return
            # Stored and fsync-ed, then /selection brought up to date, then announced.
            write_run(store, rec)
            checkpoints.drop(path, rec.id)
            drop_calibration(store)  # a new run may beat the calibrated ones: calibrated again at the end
            if rule.enabled and rec.status == "ok":  # a path that ran to its end
                rungs.finished(rec.k, *history_values(rule, kind, rec.history))
            summaries[rec.id] = run_summary(rec)
            write_selection(store, selection())
            done += 1
            failed += not rec.ok
            forecast.finished(rec.id, rec.wall_s, pruned=rec.status == "pruned",
                              history=rec.history if rec.status == "ok" else None)
            metric = f"{rec.metric:.4g} pF" if rec.ok else rec.error.splitlines()[0][:80]
            if rec.ok and math.isfinite(rec.bound_mm):  # designed for read-back: the bound first
                what = "read-back (bound ⊕ map noise)" if kind == "readback" else "read-back bound"
                metric = f"{what} {rec.initial_bound_mm:.3g} -> {rec.bound_mm:.3g} mm (min L1 {metric})"
            if rec.ok and math.isfinite(rec.error_estimate):
                metric += f" (finer mesh: C within {100 * rec.error_estimate:.2g} %)"
            elif rec.status == "ok" and ms.error_estimate:
                metric += (f" (no finer-mesh check: {beaten[rec.id]} of its k is better)" if rec.id in beaten else
                           " (no finer-mesh check: it failed, or the job is stopping)")
            say(f"[{done}/{total}] {rec.id}: {rec.status} {metric} ({rec.wall_s:.1f} s, rank {rec.rank}); "
                f"{total - done} left, ETA {duration(forecast.seconds_left(heartbeat.running()))}")

        beaten = {}  # run -> the run of its k that beat it before its check

        def answer(progress: Progress | Finished | checkpoints.Checkpoint) -> Verdict | str | None:
            if isinstance(progress, checkpoints.Checkpoint):
                why = keep(progress)
                if why is not None:
                    say(f"{progress.id}: its state at step {progress.state.iteration} is not kept ({why})")
                return None
            if isinstance(progress, Finished):
                winner = beaten_by(progress, summaries.values())
                if winner is not None:
                    beaten[progress.id] = winner
                return winner
            heartbeat.update(progress)
            return rungs.decide(progress.k, progress.iteration, progress.score) if progress.rung else None

        execute(todo, record, answer, heartbeat.tick)
        final = selection()
        write_selection(store, final)  # also when nothing was left to do
    finally:
        store.close()  # on an error too, without writing more: the file holds what was stored
    left = total - done if stop.requested else 0
    return {"runs_done": done, "runs_failed": failed, "stopped": stop.requested, "choice": choice_text(final, left)}


def _with_checkpoints(path, todo: list, say) -> tuple[list, list[str]]:
    """``todo`` with each start that has a stored state given it (``StartConfig.resume``),
    and those starts as ``id (step n)``; a state that cannot be read is said and deleted."""
    have = set(checkpoints.stored(path))
    out, resumed = [], []
    for config in todo:
        state = None
        if isinstance(config, StartConfig) and config.id in have:
            try:
                state = checkpoints.load(path, config.id)
            except ValueError as exc:
                say(f"{exc}: deleted; {config.id} runs from its beginning")
                checkpoints.drop(path, config.id)
        if state is not None:
            config = replace(config, resume=state)
            resumed.append(f"{config.id} (step {state.iteration})")
        out.append(config)
    return out, resumed


def stored_table(store, rule: PruneRule, kind: str) -> Rungs | Envelope:
    """The master's pruning table from the runs a file already holds (a resumed job prunes
    against every start of earlier sessions)."""
    if not rule.enabled:
        return Rungs(rule)
    table = rule.table(kind)
    for rid in finished_ids(store, failed=False):
        run = store["runs"][rid]
        h = run["history"]
        history = {name: h[name][()] for name in ("iteration", "J", "d", "min_l1_pF")}
        history["event"] = h["event"].asstr()[()]
        table.restore(int(run.attrs["k"]), *history_values(rule, kind, history), run.attrs["status"] == "pruned")
    return table
