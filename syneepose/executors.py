"""Where jobs run: in spawned worker processes here, each serving a few jobs and then replaced (bpy leaks over
long loops), or as Ray tasks.

A stopped run stops everything: on Ctrl-C, SIGTERM or a failed job the main process kills its workers
(SIGTERM, then SIGKILL after `GRACE_S`), and a worker whose parent dies is killed by the kernel
(PR_SET_PDEATHSIG on Linux), so no render outlives the command. Frames are written atomically, so what
stays is whole frames; the next run removes the temp files and resumes (resume.py).
"""

from __future__ import annotations

import ctypes
import os
import pickle
import signal
import socket
import sys
from multiprocessing import get_context
from multiprocessing.connection import wait

from kernel.errors import UserError

GRACE_S = 2.0  # a worker asked to stop gets this long before it is killed
# jobs a local worker process serves: a reused one saves ~2 s of imports a job, and its resident memory grows
# ~13 MiB a mini segment (570 -> 800 MiB over 18), so it is replaced after a few
JOBS_PER_PROCESS = 8


def run_local(fn, jobs: list, workers: list[dict[str, str]], progress,
              jobs_per_process: int = JOBS_PER_PROCESS) -> None:
    """Jobs on the local worker slots (`workers`: one environment dict each, e.g. the GPU it is pinned to,
    devices.py), one at a time per slot, each slot's process started with its environment and serving up to
    `jobs_per_process` jobs before a fresh one takes over; `progress(job)` as each ends. The first failure
    stops the others and is raised here."""
    ctx = get_context("spawn")
    pending = list(jobs)
    slots = [_Slot(environment) for environment in workers]
    free = list(slots)
    running = {}  # a busy slot's connection -> (slot, job)
    try:
        while pending or running:
            while pending and free:
                slot, job = free.pop(0), pending.pop(0)
                slot.start(ctx, fn, jobs_per_process)
                slot.conn.send(job)
                slot.served += 1
                running[slot.conn] = (slot, job)
            for conn in wait(list(running)):
                slot, job = running.pop(conn)
                try:
                    failed, value = conn.recv()
                except EOFError:  # the process died without a word: killed, or out of memory
                    slot.proc.join()
                    raise RuntimeError(f"the worker of {job} died (exit code {slot.proc.exitcode})") from None
                if failed:
                    raise value
                free.append(slot)
                progress(job)
        for slot in slots:
            slot.retire()
    finally:  # a failed job's worker too: it waits for its next job, and Python's exit would wait for it
        for slot in slots:
            if slot.proc is not None:
                _stop(slot.proc)


class _Slot:
    """A worker slot: its environment, and the process serving it now (None before the first job)."""

    def __init__(self, environment: dict[str, str]):
        self.environment, self.proc, self.conn, self.served = environment, None, None, 0

    def start(self, ctx, fn, jobs_per_process: int) -> None:
        """A process for the next job: the running one while it has served fewer than `jobs_per_process`."""
        if self.proc is not None and self.served < jobs_per_process:
            return
        self.retire()
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_work, args=(fn, child, os.getpid(), self.environment))
        self.proc.start()
        child.close()
        self.served = 0

    def retire(self) -> None:
        """Let the process end after its last job (an end-of-jobs message), or stop it."""
        if self.proc is None:
            return
        try:
            self.conn.send(None)
        except OSError:
            pass
        self.proc.join(GRACE_S)
        _stop(self.proc)
        self.conn.close()
        self.proc = self.conn = None


def _stop(proc) -> None:
    proc.terminate()
    proc.join(GRACE_S)
    if proc.is_alive():
        proc.kill()
        proc.join()


def _work(fn, conn, parent: int, environment: dict[str, str]) -> None:
    """Worker entry: takes its slot's variables before `fn` imports bpy, so that the GPU runtimes Cycles
    starts see them; dies with its parent, leaves Ctrl-C to it (the terminal sends it to the whole group);
    runs jobs as they come until told there are no more, sending back (failed, result or exception) for each."""
    os.environ.update(environment)
    _die_with_parent(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    while (job := conn.recv()) is not None:
        try:
            result = (False, fn(job))
        except BaseException as exc:  # it crosses the process boundary and is raised there
            result = (True, exc)
        try:
            conn.send(result)
        except (pickle.PicklingError, TypeError, AttributeError):
            conn.send((True, RuntimeError(f"{type(result[1]).__name__}: {result[1]}")))
    conn.close()


def _die_with_parent(parent: int) -> None:
    if sys.platform.startswith("linux"):
        PR_SET_PDEATHSIG = 1
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent:  # the parent died before the call took effect
        os._exit(1)


def run_ray(fn, jobs: list, address: str | None, progress, cpus: int = 1, gpus: int = 0) -> None:
    """Jobs as Ray tasks, each asking for `cpus` CPUs and `gpus` GPUs, on an existing cluster (`address`) or a
    local instance; Ray pins a task to its GPU with CUDA_VISIBLE_DEVICES (HIP_VISIBLE_DEVICES on AMD). A task
    whose worker dies is run again (up to twice) and resumes from the whole frames on disk; an interrupted
    run cancels every task it started."""
    import ray

    try:
        ray.init(address=address, ignore_reinit_error=True, log_to_driver=False)
    except ConnectionError as exc:  # a failed token check arrives as one too
        raise UserError(f"--ray-address {address}: no Ray cluster answers there ({str(exc).splitlines()[0]}); start "
                        "one with `ray start --head`, and set RAY_AUTH_MODE=token on this machine when the cluster "
                        "uses token authentication (the default of `ray start` since Ray 2.59)") from None
    if gpus and not ray.cluster_resources().get("GPU"):  # else Ray waits for one forever
        raise UserError("--device gpu: the Ray cluster has no GPU (`ray status` lists none); start its nodes on "
                        "GPU machines (ray start finds their GPUs, or give --num-gpus N), or render with --device cpu")
    # a fresh worker per task (max_calls=1); the reuse of local workers (JOBS_PER_PROCESS) is not tried under Ray
    remote = ray.remote(max_retries=2, max_calls=1, num_cpus=cpus, num_gpus=gpus)(fn)
    pending = {remote.remote(job): job for job in jobs}
    try:
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            job = pending.pop(done[0])
            ray.get(done[0])
            progress(job)
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)


def check_ray_address(address: str | None, timeout: float = 5.0) -> None:
    """Ray waits minutes for a head that is not there; a closed port is one line at once, before any write."""
    if address in (None, "auto"):
        return
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not (host and port.isdigit()):
        raise UserError(f"--ray-address {address}: give HOST:PORT of a Ray head (`ray start --head` prints it)")
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as exc:
        raise UserError(f"--ray-address {address}: nothing answers there ({exc.strerror or exc}); start a Ray head "
                        "with `ray start --head` or give its address") from None
