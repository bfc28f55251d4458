"""Executors for a take's chunks (``wface.tracking.sequence.track_sequence``): a Dask cluster, local or
on a running scheduler.

A chunk's arguments are large (the model, and for a refinement pass the previous pass's frame records:
~270 KB a frame at 5K tets, 216 MB for half of a 1,590-frame take), so they are scattered to the
workers before the task is submitted instead of riding inside the task graph (Dask warns of, and
serialises through the scheduler, graphs of that size).
"""

from __future__ import annotations

import contextlib
import logging
import math
import signal

__all__ = ["ScatteringExecutor", "dask_executor"]


class ScatteringExecutor:
    """``concurrent.futures``-style ``submit`` on a Dask ``Client`` that scatters the arguments first.

    Each argument is scattered under a key hashed from its content (``Client.scatter(hash=True)``), so
    the model, the same in every chunk, is one key on the cluster; an argument is released with the
    task that holds it."""

    def __init__(self, client):
        self.client = client

    def submit(self, fn, *args):
        futures = [a if isinstance(a, (bool, int, float, str, type(None))) else self._scatter(a) for a in args]
        return self.client.submit(fn, *futures, pure=False)

    def _scatter(self, arg):
        return self.client.scatter([arg])[0]  # a list as one object (``scatter`` of a list scatters each item)


@contextlib.contextmanager
def _workers_ignore_interrupts():
    """Start worker processes with Ctrl-C ignored: the terminal sends SIGINT to the whole process group, and
    each worker printed its own KeyboardInterrupt traceback (2-4 of them, 40-70 lines) before the command's
    one line. The command itself stops the cluster when interrupted."""
    try:
        old = signal.signal(signal.SIGINT, signal.SIG_IGN)  # inherited by the spawned processes
    except ValueError:  # not the main thread: leave the signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def dask_executor(*, workers: int = 1, scheduler: str | None = None, n_frames: int, chunk_size: int | None = None):
    """(executor, chunk_size, close) for ``track_sequence``: a ``ScatteringExecutor`` on a running
    scheduler (``scheduler`` address) or on a local cluster of ``workers`` processes, or (None,
    chunk_size, no-op) to run in-process. The default chunk size splits the take evenly over the workers."""
    if not (scheduler or workers > 1):
        return None, chunk_size, lambda: None
    from distributed import Client, LocalCluster

    if scheduler:
        client = Client(scheduler)
        workers = max(1, len(client.scheduler_info()["workers"]))
        closers = [client.close]
    else:
        with _workers_ignore_interrupts():
            cluster = LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=None,
                silence_logs=logging.ERROR,
            )
        client = Client(cluster)
        closers = [client.close, cluster.close]
    chunk = chunk_size or math.ceil(n_frames / workers)
    return ScatteringExecutor(client), chunk, lambda: [c() for c in closers]
