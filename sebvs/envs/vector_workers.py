"""Threads that each own some envs of a shared-process vector env (sebvs/envs/vector.py).

    workers = PinnedWorkers(2)
    results = workers.run([job_0, job_1])     # job w runs on thread w, all at once
    workers.close()

An env's GL context is current in the thread that made it, and EGL refuses to make it
current in a second one while it is, so every call on an env (its construction, resets,
steps, close) runs on the one thread that owns it. With count 1 there is no thread: the
jobs run in the caller's, one after the other. MuJoCo's renders and physics and numpy's
whole-array passes release the GIL, so on a machine with free cores the envs of
different threads step at the same time; each env's own work stays in order on its
thread, so the results are the same as one thread gives.
"""
from __future__ import annotations

import queue
import threading
from typing import Any, Callable


class PinnedWorkers:
    """`count` threads; the w-th job of a run() always runs on thread w.

    Parameters:
        count: how many (>= 1; 1: no thread, the caller runs the jobs).
    """

    def __init__(self, count: int) -> None:
        if isinstance(count, bool) or not isinstance(count, int) or count < 1:
            raise ValueError(f"threads must be an integer >= 1, got {count!r}")
        self.count = count
        self._jobs: list[queue.Queue] = []
        self._done: queue.Queue = queue.Queue()
        self._threads: list[threading.Thread] = []
        if count > 1:
            for w in range(count):
                jobs: queue.Queue = queue.Queue()
                t = threading.Thread(target=self._loop, args=(w, jobs),
                                     name=f"sebvs-vector-{w}", daemon=True)
                t.start()
                self._jobs.append(jobs)
                self._threads.append(t)

    def _loop(self, w: int, jobs: queue.Queue) -> None:
        while True:
            job = jobs.get()
            if job is None:
                return
            try:
                self._done.put((w, True, job()))
            except BaseException as exc:          # handed to the caller of run()
                self._done.put((w, False, exc))

    def run(self, jobs: list[Callable[[], Any] | None]) -> list[Any]:
        """Run job w on thread w (None: nothing there), wait for all of them.

        Parameters:
            jobs: at most `count` callables (or None).

        Returns:
            Each job's result (None where there was no job). The first worker's exception,
            by worker order, is raised once all have finished.
        """
        if len(jobs) > self.count:
            raise ValueError(f"{len(jobs)} jobs for {self.count} workers")
        results: list[Any] = [None] * len(jobs)
        if not self._threads:
            for w, job in enumerate(jobs):
                if job is not None:
                    results[w] = job()
            return results
        pending = 0
        for w, job in enumerate(jobs):
            if job is not None:
                self._jobs[w].put(job)
                pending += 1
        errors: dict[int, BaseException] = {}
        for _ in range(pending):
            w, ok, value = self._done.get()
            if ok:
                results[w] = value
            else:
                errors[w] = value
        if errors:
            raise errors[min(errors)]
        return results

    def close(self) -> None:
        """Stop the threads (after their current job)."""
        for jobs in self._jobs:
            jobs.put(None)
        for t in self._threads:
            t.join()
        self._jobs, self._threads = [], []
