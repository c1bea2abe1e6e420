"""Master/worker task farming over MPI, shared by the multi-start service and the
calibration's training simulations.

The master hands out tasks one at a time to whichever worker speaks first (dynamic
scheduling: Iprobe plus 10 ms sleeps, so an idle master costs no core) and passes each
result to a callback; a worker says "ready", then loops: receive a task, send back its
result, until told to stop. While on a task a worker may *ask* the master a question
(a pruning checkpoint) and wait for its answer. Tasks, questions, answers and results are
pickled Python objects.

SIGTERM (what SLURM sends at the time limit), SIGUSR1 (passed on by ``mpirun``) and Ctrl-C
set :class:`Stop`, which makes the master hand out nothing more. A worker that gets SIGTERM
or SIGUSR1 does not die of it: it tells the master ("halt"), which stops the job the same
way, so a signal to any rank is a clean stop of the whole job. The master says so at once,
in one line (``stopping (SIGTERM to rank 0): ...``), and writes the reason to
``$MSCAP_STOP_FILE`` when set (the job scripts: a launcher that ends the job with a non-zero
status after the signal, as ``mpirun`` does on SIGTERM, still reports mscap's clean stop).
A stop is graceful first: the master answers a worker's next question with "abandon"
(the worker drops its task, which is not recorded and runs again on resume), records the
results that still arrive, and lets every worker go; all ranks then end normally, so
``srun`` and ``mpirun`` exit 0. Workers still busy after :data:`STOP_GRACE_S` (a task
that asks no questions, e.g. a finer-mesh check) are aborted with the job.

While waiting, the master calls ``tick(busy)`` (``{worker: (task, since)}``) so a service
can report on its busy workers (:class:`mscap.service.heartbeat.Heartbeat`).

:func:`run` is the one skeleton both services use: workers serve, the master plans its
tasks and records results, and a stop leaves what was recorded. An exception on any rank
ends the whole job (:func:`abort_at_exit`), never leaves the others spinning.
"""

from __future__ import annotations

import atexit
import os
import signal
import time
from typing import Any, Callable, Iterable, TypeVar

Result = TypeVar("Result")

__all__ = ["TAGS", "STOP_SIGNALS", "STOP_GRACE_S", "STOP_FILE_ENV", "Stop", "Abandoned", "pass_stop_on", "Crew", "farm",
           "serve", "ask_master", "abort_at_exit", "release", "quiet_barrier", "run"]

#: Message tags between master and workers, in one place.
TAGS = {"ready": 1, "work": 2, "result": 3, "stop": 4, "ask": 5, "answer": 6, "abandon": 7, "halt": 8}

#: After a stop, how long the master waits for busy workers to reach a question (and drop
#: their task) or to finish it, before the job is aborted with them.
STOP_GRACE_S = 60.0

#: The environment variable naming a file the master writes when it begins a clean stop
#: (``stopping <reason>``) and when it has stopped (``stopped``); an error after the stop
#: began writes ``error``. The job scripts read it (slurm/common.sh).
STOP_FILE_ENV = "MSCAP_STOP_FILE"


class Abandoned(BaseException):
    """Raised by a worker's ``ask`` when the master is stopping: the task is dropped. Like
    ``KeyboardInterrupt`` it is a stop, not an error, so it passes the ``except Exception``
    that stores a start's error as a failed run."""


#: The signals that ask the master to stop: SIGTERM (SLURM's time limit, ``scancel``) and
#: SIGUSR1 (what OpenMPI's ``mpirun`` passes on to every rank without killing the job;
#: the SLURM scripts send it to an ``mpirun`` inside the allocation, slurm/README.md).
STOP_SIGNALS = (signal.SIGTERM, signal.SIGUSR1)


class Stop:
    """Turns :data:`STOP_SIGNALS` into a flag the master polls; :attr:`reason` says what
    asked (``SIGTERM to rank 0``, ``SIGUSR1 to rank 2``, ``Ctrl-C``), and :meth:`notice`
    says it once (``say``), as soon as the master sees it."""

    def __init__(self, say: Callable[[str], None] | None = None):
        self.requested = False
        self.reason = ""
        self.noticed = False
        self._say = say
        self._previous = {s: signal.signal(s, self._handle) for s in STOP_SIGNALS}

    def _handle(self, signum, frame):
        self.request(f"{signal.Signals(signum).name} to rank 0")

    def request(self, reason: str) -> None:
        if not self.requested:
            self.requested, self.reason = True, reason

    def notice(self) -> None:
        """Say, once, that the job is stopping and why; write :data:`STOP_FILE_ENV`. What
        has been recorded is on disk by then (both services store each result as it comes):
        a launcher that kills the ranks right after (``mpirun`` on SIGTERM, 1 s later)
        loses only the busy workers' tasks, which run again on resume."""
        if self.noticed or not self.requested:
            return
        self.noticed = True
        if self._say is not None:
            self._say(f"stopping ({self.reason}): everything finished is stored; no new task is handed "
                      f"out and busy workers stop at their next checkpoint (at most {STOP_GRACE_S:.0f} s)")
        write_stop_file(f"stopping {self.reason}")

    def restore(self):
        for s, previous in self._previous.items():
            signal.signal(s, previous)


def write_stop_file(text: str) -> None:
    """``text`` into the file :data:`STOP_FILE_ENV` names, if set (a failure to write it is
    the launcher's loss, not the job's: ignored)."""
    path = os.environ.get(STOP_FILE_ENV)
    if path:
        try:
            with open(path, "w", encoding="utf-8") as f:
                f.write(text + "\n")
        except OSError:
            pass


def pass_stop_on(comm) -> None:
    """Worker side: a :data:`STOP_SIGNALS` signal to this rank asks the master to stop the
    job (one "halt" message, sent once) instead of ending the rank. SLURM signals every task
    of a step and ``mpirun`` every rank; a worker that died of it would take its finished but
    unsent result with it, and a signal to one worker alone (``kill -TERM``) is a stop of the
    job like one to the master. The handler runs between Python bytecodes, never inside an
    MPI call, and the message is a few bytes (sent eagerly)."""
    told = []

    def handle(signum, frame):
        if not told:
            told.append(signum)
            comm.send(signal.Signals(signum).name, dest=0, tag=TAGS["halt"])

    for s in STOP_SIGNALS:
        signal.signal(s, handle)


class Crew:
    """Master side: the workers of a job across several :func:`farm` calls (a fit farms one
    batch of forward simulations per iteration): how many have not yet said "ready", and
    which wait for the next batch (parked)."""

    def __init__(self, comm):
        self.unready = comm.Get_size() - 1
        self.parked: list[int] = []


def farm(comm, todo: Iterable, record: Callable[[Any], None], stop: Stop,
         answer: Callable[[Any], Any] | None = None, tick: Callable[[dict], None] | None = None,
         grace_s: float = STOP_GRACE_S, crew: Crew | None = None, keep: bool = False) -> int:
    """Master side: every task of ``todo`` to a worker, ``record(result)`` for each
    result, ``answer(question)`` sent back to a worker that asks, ``tick(busy)`` while
    waiting. Returns when all workers are stopped (with ``keep``: when every task is done,
    the workers parked in ``crew`` for the next call), or once ``stop`` has been set for
    ``grace_s`` seconds; the number of workers then still busy. A call without ``keep``
    lets every worker of ``crew`` go (``todo`` may be empty)."""
    from mpi4py import MPI

    status = MPI.Status()
    crew = crew or Crew(comm)
    queue = list(todo)
    busy: dict[int, tuple[Any, float]] = {}  # worker -> (task, handed out at)

    def next_task(worker: int) -> None:
        """Hand ``worker`` a task, park it (``keep``) or let it go."""
        if queue and not stop.requested:
            busy[worker] = (queue.pop(0), time.monotonic())
            comm.send(busy[worker][0], dest=worker, tag=TAGS["work"])
        elif keep and not stop.requested:
            crew.parked.append(worker)
        else:
            comm.send(None, dest=worker, tag=TAGS["stop"])

    parked, crew.parked = crew.parked, []
    for worker in parked:
        next_task(worker)
    stopping = None
    # Every unready worker says "ready" first, then returns results; with ``keep`` the
    # unready are waited for only while tasks are left for them.
    while busy or crew.unready and (not keep or queue and not stop.requested):
        while not comm.Iprobe(source=MPI.ANY_SOURCE, tag=MPI.ANY_TAG, status=status):
            if stop.requested:
                stop.notice()  # once, at once
                stopping = stopping or time.monotonic()
                if time.monotonic() - stopping > grace_s:
                    return len(busy)
                if keep and not busy:
                    return 0
            if tick is not None:
                tick(busy)
            time.sleep(0.01)
        message = comm.recv(source=status.Get_source(), tag=status.Get_tag(), status=status)
        worker = status.Get_source()
        if status.Get_tag() == TAGS["halt"]:  # a signal to a worker: the job stops
            stop.request(f"{message} to rank {worker}")
        if stop.requested:
            stop.notice()  # once, at once, even while messages keep coming
        if status.Get_tag() == TAGS["halt"]:
            continue
        if status.Get_tag() == TAGS["ask"]:  # a busy worker waits for the answer
            if stop.requested:
                comm.send(None, dest=worker, tag=TAGS["abandon"])
            else:
                comm.send(None if answer is None else answer(message), dest=worker, tag=TAGS["answer"])
            continue
        if status.Get_tag() == TAGS["ready"]:
            crew.unready -= 1
        if status.Get_tag() == TAGS["result"]:
            busy.pop(worker, None)
            if message is not None:  # None: an abandoned task
                record(message)
        next_task(worker)
    return 0


#: How often a worker waiting for its next task looks for it (s): between a fit's batches a
#: worker may wait as long as the master's step takes, and OpenMPI's blocking receive
#: polls at full speed.
SERVE_POLL_S = 0.002


def serve(comm, work: Callable[[Any], Any]) -> None:
    """Worker side: ``work(task)`` for every task the master sends, until "stop"."""
    from mpi4py import MPI

    status = MPI.Status()
    comm.send(None, dest=0, tag=TAGS["ready"])
    while True:
        while not comm.Iprobe(source=0, tag=MPI.ANY_TAG):  # a blocking receive spins a core
            time.sleep(SERVE_POLL_S)
        task = comm.recv(source=0, tag=MPI.ANY_TAG, status=status)
        if status.Get_tag() == TAGS["stop"]:
            return
        try:
            result = work(task)
        except Abandoned:
            result = None
        comm.send(result, dest=0, tag=TAGS["result"])


def ask_master(comm) -> Callable[[Any], Any]:
    """Worker side: ``ask(question)`` sends a question to the master and returns its
    answer (the master answers between the other workers' messages), or raises
    :class:`Abandoned` when the master is stopping."""
    from mpi4py import MPI

    def ask(question):
        status = MPI.Status()
        comm.send(question, dest=0, tag=TAGS["ask"])
        answer = comm.recv(source=0, tag=MPI.ANY_TAG, status=status)
        if status.Get_tag() == TAGS["abandon"]:
            raise Abandoned
        return answer
    return ask


def abort_at_exit(comm, exc: BaseException) -> None:
    """End every rank of the job once this process exits on ``exc``.

    The error first takes its usual route (``mscap: error: ...`` from the command line, or
    a traceback), so it is printed once, by the rank that failed; then, at interpreter
    exit, ``MPI_Abort`` ends the others, which would otherwise wait forever for this rank
    (a master that stopped listening, a worker that stopped answering). The exit status is
    2 for an :class:`~mscap.errors.MscapError`, 130 for Ctrl-C, 1 otherwise. Nothing
    happens on a single rank."""
    if comm.Get_size() == 1:
        return
    from mscap.errors import MscapError

    code = 2 if isinstance(exc, MscapError) else 130 if isinstance(exc, KeyboardInterrupt) else 1
    atexit.register(comm.Abort, code)


def release(comm) -> None:
    """Master side, before any task was sent: let every worker go (the master failed
    early, e.g. on a refused file; the workers must not wait forever)."""
    for worker in range(1, comm.Get_size()):
        comm.send(None, dest=worker, tag=TAGS["stop"])
    quiet_barrier(comm)


#: How often a rank waiting in :func:`quiet_barrier` looks whether the others arrived (s).
BARRIER_POLL_S = 0.05


def quiet_barrier(comm) -> None:
    """Wait for every rank without using a core: a non-blocking barrier tested every
    :data:`BARRIER_POLL_S`. Every rank passes here before it leaves :func:`run`, so none
    waits in ``MPI_Finalize``, where OpenMPI polls at full speed: on the paper poking
    multi-start the worker that finished 12 minutes before the other spent them there: 4,637
    CPU-s by ``/usr/bin/time`` against its starts' 3,916 (docs/performance.md §10)."""
    if comm.Get_size() == 1:
        return
    request = comm.Ibarrier()
    while not request.Test():
        time.sleep(BARRIER_POLL_S)


#: ``execute(tasks, record, answer=None, tick=None)``: the master's call that gets every task done.
Execute = Callable[..., None]


def run(comm, make_work: Callable[[Callable[[Any], Any] | None], Callable[[Any], Any]],
        master: Callable[[Execute, Stop], Result], stopped_message: str,
        say: Callable[[str], None], batches: bool = False) -> Result | None:
    """The MPI master/worker skeleton of every service.

    Ranks > 0 serve ``make_work(ask)`` until told to stop and return ``None``; ``ask``
    puts a question to the master. Rank 0 returns ``master(execute, stop)``: the master
    opens its files, plans its tasks and calls ``execute(tasks, record, answer, tick)``
    once, which runs them here on a single rank (``ask`` is then ``answer`` itself) or
    farms them out, calling ``record(result)`` for each result, ``answer(question)`` for
    each question and ``tick(busy)`` while it waits. If the master fails before
    ``execute`` the workers are released; if it fails later, or a worker fails, the
    error is printed once by its rank and the whole job is aborted
    (:func:`abort_at_exit`): no rank is left waiting. SIGTERM or SIGUSR1 to any rank, or
    Ctrl-C, set ``stop`` (rank 0 says so at once, :meth:`Stop.notice`; nothing more is handed
    out, busy workers drop their task at their next question, the master closes its files as
    usual), then rank 0 says ``stopped_message``; workers still busy after
    :data:`STOP_GRACE_S` are aborted with the job.

    With ``batches`` the master may call ``execute`` any number of times (a fit: one batch
    of forward simulations per iteration); the workers wait between batches and are let
    go when ``master`` returns."""
    if comm.Get_rank() != 0:
        pass_stop_on(comm)
        try:
            serve(comm, make_work(ask_master(comm)))
        except BaseException as exc:
            abort_at_exit(comm, exc)
            raise
        quiet_barrier(comm)
        return None
    stop, farming, left, crew = Stop(say), False, 0, Crew(comm)

    def execute(tasks: Iterable, record: Callable[[Any], None], answer: Callable[[Any], Any] | None = None,
                tick: Callable[[dict], None] | None = None) -> None:
        nonlocal farming, left
        farming = True
        try:
            if comm.Get_size() == 1:
                busy = {}

                def ask(question):
                    if stop.requested:
                        raise Abandoned
                    reply = None if answer is None else answer(question)
                    if tick is not None:
                        tick(busy)
                    return reply

                work = make_work(ask)
                for task in tasks:
                    if stop.requested:
                        stop.notice()
                        break
                    busy[0] = (task, time.monotonic())
                    record(work(task))
            else:
                left = farm(comm, tasks, record, stop, answer, tick, crew=crew, keep=batches)
        except KeyboardInterrupt:
            stop.request("Ctrl-C")
            stop.notice()
        except Abandoned:
            stop.notice()

    try:
        result = master(execute, stop)
        if batches and comm.Get_size() > 1 and not left:
            farm(comm, [], record=lambda result: None, stop=stop, crew=crew)  # let the kept workers go
    except BaseException as exc:
        if stop.noticed:
            write_stop_file("error")  # the stop began, but the job did not end cleanly
        if not farming:
            release(comm)  # let the workers go before the error reaches main()
        else:
            abort_at_exit(comm, exc)  # workers may be busy or waiting: end them all
        raise
    finally:
        stop.restore()
    if stop.requested:
        stop.notice()
        say(stopped_message)
        write_stop_file("stopped")
        if left:
            comm.Abort(0)
    quiet_barrier(comm)
    return result
