"""Master/worker task farming over MPI, shared by the multi-start service and the
calibration's training simulations.

The master hands out tasks one at a time to whichever worker speaks first (dynamic
scheduling: Iprobe plus 10 ms sleeps, so an idle master costs no core) and passes each
result to a callback; a worker says "ready", then loops: receive a task, send back its
result, until told to stop. While on a task a worker may *ask* the master a question
(a pruning checkpoint) and wait for its answer. Tasks, questions, answers and results are
pickled Python objects. SIGTERM (what
SLURM sends at the time limit), SIGUSR1 (passed on by ``mpirun``) and Ctrl-C set
:class:`Stop`, which makes the master hand out nothing more; workers ignore both signals.

:func:`run` is the one skeleton both services use: workers serve, the master plans its
tasks and records results, and a stop leaves what was recorded and aborts busy workers.
"""

from __future__ import annotations

import signal
import time
from typing import Any, Callable, Iterable, TypeVar

Result = TypeVar("Result")

__all__ = ["TAGS", "STOP_SIGNALS", "Stop", "ignore_stop_signals", "farm", "serve", "ask_master", "release", "run"]

#: Message tags between master and workers, in one place.
TAGS = {"ready": 1, "work": 2, "result": 3, "stop": 4, "ask": 5, "answer": 6}


#: The signals that ask the master to stop: SIGTERM (SLURM's time limit, ``scancel``) and
#: SIGUSR1 (what OpenMPI's ``mpirun`` passes on to every rank without killing the job;
#: the SLURM scripts send it to an ``mpirun`` inside the allocation, slurm/README.md).
STOP_SIGNALS = (signal.SIGTERM, signal.SIGUSR1)


class Stop:
    """Turns :data:`STOP_SIGNALS` into a flag the master polls."""

    def __init__(self):
        self.requested = False
        self._previous = {s: signal.signal(s, self._handle) for s in STOP_SIGNALS}

    def _handle(self, signum, frame):
        self.requested = True

    def restore(self):
        for s, previous in self._previous.items():
            signal.signal(s, previous)


def ignore_stop_signals() -> None:
    """Worker side: leave :data:`STOP_SIGNALS` to the master. SLURM signals every task
    of a step and ``mpirun`` every rank; a worker that died of it would take its finished
    but unsent result with it, while the master stops cleanly and aborts busy workers."""
    for s in STOP_SIGNALS:
        signal.signal(s, signal.SIG_IGN)


def farm(comm, todo: Iterable, record: Callable[[Any], None], stop: Stop,
         answer: Callable[[Any], Any] | None = None) -> None:
    """Master side: every task of ``todo`` to a worker, ``record(result)`` for each
    result, ``answer(question)`` sent back to a worker that asks; returns when all
    workers are stopped (or at once when ``stop`` is set)."""
    from mpi4py import MPI

    status = MPI.Status()
    queue = list(todo)
    busy = comm.Get_size() - 1  # every worker says "ready" first, then returns results
    while busy:
        while not comm.Iprobe(source=MPI.ANY_SOURCE, tag=MPI.ANY_TAG, status=status):
            if stop.requested:
                return
            time.sleep(0.01)
        message = comm.recv(source=status.Get_source(), tag=status.Get_tag(), status=status)
        worker = status.Get_source()
        if status.Get_tag() == TAGS["ask"]:  # a busy worker waits for the answer
            comm.send(None if answer is None else answer(message), dest=worker, tag=TAGS["answer"])
            continue
        if status.Get_tag() == TAGS["result"]:
            record(message)
        if queue and not stop.requested:
            comm.send(queue.pop(0), dest=worker, tag=TAGS["work"])
        else:
            comm.send(None, dest=worker, tag=TAGS["stop"])
            busy -= 1


def serve(comm, work: Callable[[Any], Any]) -> None:
    """Worker side: ``work(task)`` for every task the master sends, until "stop"."""
    from mpi4py import MPI

    status = MPI.Status()
    comm.send(None, dest=0, tag=TAGS["ready"])
    while True:
        task = comm.recv(source=0, tag=MPI.ANY_TAG, status=status)
        if status.Get_tag() == TAGS["stop"]:
            return
        comm.send(work(task), dest=0, tag=TAGS["result"])


def ask_master(comm) -> Callable[[Any], Any]:
    """Worker side: ``ask(question)`` sends a question to the master and returns its
    answer (the master answers between the other workers' messages)."""
    def ask(question):
        comm.send(question, dest=0, tag=TAGS["ask"])
        return comm.recv(source=0, tag=TAGS["answer"])
    return ask


def release(comm) -> None:
    """Master side, before any task was sent: let every worker go (the master failed
    early, e.g. on a refused file; the workers must not wait forever)."""
    for worker in range(1, comm.Get_size()):
        comm.send(None, dest=worker, tag=TAGS["stop"])


#: ``execute(tasks, record, answer=None)``: the master's one call that gets every task done.
Execute = Callable[..., None]


def run(comm, make_work: Callable[[Callable[[Any], Any] | None], Callable[[Any], Any]],
        master: Callable[[Execute, Stop], Result], stopped_message: str,
        say: Callable[[str], None]) -> Result | None:
    """The MPI master/worker skeleton of every service.

    Ranks > 0 serve ``make_work(ask)`` until told to stop and return ``None``; ``ask``
    puts a question to the master. Rank 0 returns ``master(execute, stop)``: the master
    opens its files, plans its tasks and calls ``execute(tasks, record, answer)`` once,
    which runs them here on a single rank (``ask`` is then ``answer`` itself) or farms them
    out, calling ``record(result)`` for each result and ``answer(question)`` for each
    question. If the master fails before ``execute`` the
    workers are released; SIGTERM or Ctrl-C set ``stop`` (nothing more is handed out, the
    master closes its files as usual), then rank 0 says ``stopped_message`` and aborts the
    workers still busy (a busy start cannot be interrupted otherwise)."""
    if comm.Get_rank() != 0:
        ignore_stop_signals()
        serve(comm, make_work(ask_master(comm)))
        return None
    stop, farming = Stop(), False

    def execute(tasks: Iterable, record: Callable[[Any], None], answer: Callable[[Any], Any] | None = None) -> None:
        nonlocal farming
        farming = True
        try:
            if comm.Get_size() == 1:
                work = make_work(answer)
                for task in tasks:
                    if stop.requested:
                        break
                    record(work(task))
            else:
                farm(comm, tasks, record, stop, answer)
        except KeyboardInterrupt:
            stop.requested = True

    try:
        result = master(execute, stop)
    except BaseException:
        if not farming:
            release(comm)  # let the workers go before the error reaches main()
        raise
    finally:
        stop.restore()
    if stop.requested:
        say(stopped_message)
        if comm.Get_size() > 1:
            comm.Abort(0)
    return result
