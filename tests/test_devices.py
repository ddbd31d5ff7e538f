"""`--device gpu` on several GPUs: which GPUs a machine shows, which one each local worker is pinned to, that
the worker process starts with it, and that Ray gives each task one GPU. No GPU and no render needed: the
GPUs come as the environment and `nvidia-smi -L` text a machine would give, and Ray is told it has two.
(Which Cycles backend renders, and the one line when Cycles lists no GPU: tests/test_render.py.)
"""

import json
import multiprocessing
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from kernel.errors import UserError
from syneepose import __main__ as syneepose_cli
from syneepose.devices import NVIDIA_SMI, VisibleGpus, visible_gpus, worker_environments
from syneepose.executors import run_local, run_ray

SMI_TWO = """GPU 0: NVIDIA RTX A4000 (UUID: GPU-0e3c6e4e-5c1a-4f57-9d1b-2b5e1f0e9a11)
GPU 1: NVIDIA RTX A4000 (UUID: GPU-7d2f8a90-3b64-4c2e-8e0f-6a1c9b7d5e22)
"""
SMI_MIG = """GPU 0: NVIDIA A100-SXM4-40GB (UUID: GPU-5f8c1a2b-0d3e-4f6a-9b7c-1e2d3f4a5b6c)
  MIG 3g.20gb     Device  0: (UUID: MIG-11111111-2222-3333-4444-555555555555)
  MIG 3g.20gb     Device  1: (UUID: MIG-66666666-7777-8888-9999-000000000000)
"""


@pytest.mark.parametrize("environ, smi, variable, ids", [
    ({}, SMI_TWO, "CUDA_VISIBLE_DEVICES", ("0", "1")),
    ({}, SMI_MIG, "CUDA_VISIBLE_DEVICES", ("0",)),  # MIG slices are not GPUs of their own here
    ({}, "", "CUDA_VISIBLE_DEVICES", ()),  # nvidia-smi failed: no driver
    ({"CUDA_VISIBLE_DEVICES": "2,3"}, SMI_TWO * 2, "CUDA_VISIBLE_DEVICES", ("2", "3")),  # a scheduler's choice wins
    ({"CUDA_VISIBLE_DEVICES": "GPU-0e3c6e4e"}, None, "CUDA_VISIBLE_DEVICES", ("GPU-0e3c6e4e",)),
    ({"CUDA_VISIBLE_DEVICES": ""}, SMI_TWO, "CUDA_VISIBLE_DEVICES", ()),
    ({"CUDA_VISIBLE_DEVICES": "-1"}, SMI_TWO, "CUDA_VISIBLE_DEVICES", ()),
    ({"CUDA_VISIBLE_DEVICES": "0,-1,1"}, None, "CUDA_VISIBLE_DEVICES", ("0",)),  # CUDA stops at the bad index
    ({"CUDA_VISIBLE_DEVICES": "NoDevFiles"}, None, "CUDA_VISIBLE_DEVICES", ()),
    ({"HIP_VISIBLE_DEVICES": "0, 1"}, None, "HIP_VISIBLE_DEVICES", ("0", "1")),
])
def test_visible_gpus_respect_the_schedulers_variables_before_nvidia_smi(environ, smi, variable, ids):
    visible = visible_gpus(environ, smi)
    assert (visible.variable, visible.ids) == (variable, ids)


def test_visible_gpus_are_unknown_without_a_variable_or_nvidia_smi():
    assert visible_gpus({"PATH": "/usr/bin"}, None) is None


CUDA = "CUDA_VISIBLE_DEVICES"
FOUR = VisibleGpus(CUDA, ("0", "1", "2", "3"), NVIDIA_SMI)
PCI = {"CUDA_DEVICE_ORDER": "PCI_BUS_ID"}  # nvidia-smi's numbering, which --gpus counts in


@pytest.mark.parametrize("gpus, workers, visible, expected", [
    (None, None, FOUR, [{CUDA: g, **PCI} for g in "0123"]),  # one worker per GPU
    ("all", None, FOUR, [{CUDA: g, **PCI} for g in "0123"]),
    ("0,1,3", None, FOUR, [{CUDA: g, **PCI} for g in "013"]),
    ("3,0", 4, FOUR, [{CUDA: g, **PCI} for g in "3030"]),  # --workers spreads over the chosen GPUs in turn
    (None, 1, FOUR, [{CUDA: "0", **PCI}]),
    # a scheduler left GPUs 2 and 3 visible: --gpus counts among them, and the worker keeps its numbering
    ("1", None, VisibleGpus(CUDA, ("2", "3"), "CUDA_VISIBLE_DEVICES='2,3'"), [{CUDA: "3"}]),
    (None, None, VisibleGpus("HIP_VISIBLE_DEVICES", ("0", "1"), "HIP_VISIBLE_DEVICES='0,1'"),
     [{"HIP_VISIBLE_DEVICES": "0"}, {"HIP_VISIBLE_DEVICES": "1"}]),
    (None, None, None, [{}]),  # GPUs not countable (AMD without HIP_VISIBLE_DEVICES, a Mac): Cycles picks
    ("all", 2, None, [{}, {}]),
])
def test_each_worker_is_pinned_to_one_gpu(gpus, workers, visible, expected):
    assert worker_environments(gpus, workers, visible) == expected


@pytest.mark.parametrize("gpus, visible, words", [
    (None, VisibleGpus(CUDA, (), NVIDIA_SMI), ["--device gpu: no GPU found", "--device cpu"]),
    ("all", VisibleGpus(CUDA, (), "CUDA_VISIBLE_DEVICES=''"), ["no GPU found", "CUDA_VISIBLE_DEVICES=''"]),
    ("5", VisibleGpus(CUDA, ("0", "1"), NVIDIA_SMI), ["--gpus 5", "2 GPUs", "below 2"]),
    ("0,0", FOUR, ["--gpus 0,0", "each GPU once"]),
    ("-1", FOUR, ["--gpus -1", "from 0"]),
    ("gpu0", FOUR, ["--gpus 'gpu0'", "0,1,3"]),
    ("0", None, ["--gpus 0", "cannot count", "HIP_VISIBLE_DEVICES=0,1"]),
])
def test_gpu_choices_that_cannot_be_met_are_one_line_naming_the_fix(gpus, visible, words):
    with pytest.raises(UserError) as raised:
        worker_environments(gpus, None, visible)
    message = str(raised.value)
    assert "\n" not in message
    for word in words:
        assert word in message, message


def _record(path: str) -> None:
    """A job that notes what its process was started with, and when it ran."""
    start = time.monotonic()
    time.sleep(1.0)
    Path(path).write_text(json.dumps({"gpu": os.environ.get(CUDA), "order": os.environ.get("CUDA_DEVICE_ORDER"),
                                      "bpy": "bpy" in sys.modules, "start": start, "end": time.monotonic()}))


def test_local_workers_start_each_job_pinned_to_their_own_gpu(tmp_path, monkeypatch):
    monkeypatch.setenv(CUDA, "0,1")  # the parent's own, which its workers narrow
    jobs = [str(tmp_path / f"{i}.json") for i in range(5)]
    done = []
    run_local(_record, jobs, worker_environments(None, None, visible_gpus(os.environ, None)), done.append)
    assert sorted(done) == jobs
    runs = [json.loads(Path(j).read_text()) for j in jobs]
    assert {r["gpu"] for r in runs} == {"0", "1"} and not any(r["bpy"] or r["order"] for r in runs)
    overlapping = [(a, b) for i, a in enumerate(runs) for b in runs[i + 1:]
                   if a["start"] < b["end"] and b["start"] < a["end"]]
    assert overlapping, "the two workers never ran at once"
    assert all(a["gpu"] != b["gpu"] for a, b in overlapping)  # never two jobs on one GPU
    assert os.environ[CUDA] == "0,1"  # the parent is untouched


def _pid(path: str) -> None:
    Path(path).write_text(str(os.getpid()))


def test_a_local_worker_process_serves_several_jobs_then_a_fresh_one_takes_over(tmp_path):
    """A worker process's imports (bpy, numpy, the robot models: about 2 s) are paid once for several jobs,
    and a process is replaced after `jobs_per_process` of them, so Blender's leaks cannot pile up."""
    jobs = [str(tmp_path / f"{i}.txt") for i in range(5)]
    done = []
    run_local(_pid, jobs, [{}], done.append, jobs_per_process=2)
    assert done == jobs
    pids = [Path(j).read_text() for j in jobs]
    assert pids[0] == pids[1] != pids[2] == pids[3] != pids[4]
    assert len(set(pids)) == 3 and str(os.getpid()) not in pids


def _fail(path: str) -> None:
    raise ValueError(f"no such scene: {path}")


def test_a_failed_job_stops_its_reused_worker_too():
    """The failed job's worker would wait for its next job, and Python's exit would wait for that worker."""
    with pytest.raises(ValueError, match="no such scene: a"):
        run_local(_fail, ["a", "b"], [{}], lambda job: None)
    assert not multiprocessing.active_children()


def test_a_worker_sets_its_gpu_before_bpy_is_imported():
    """A spawned worker imports the command's and the jobs' modules before it runs a job: none imports bpy,
    so Cycles' GPU runtimes start after the worker has its CUDA_VISIBLE_DEVICES."""
    code = ("import sys, syneepose.__main__, syneepose.jobs, syneepose.executors; "
            "print('bpy' in sys.modules)")
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True).stdout.strip() == "False"


@pytest.mark.parametrize("environ, args, words", [
    ({CUDA: "0,1"}, ["--device", "gpu", "--gpus", "5"], ["--gpus 5", "2 GPUs", "CUDA_VISIBLE_DEVICES='0,1'"]),
    ({CUDA: ""}, ["--device", "gpu"], ["--device gpu: no GPU found", "--device cpu"]),
    ({CUDA: "0,1"}, ["--gpus", "0"], ["--gpus 0 goes with --device gpu"]),
    ({CUDA: "0,1"}, ["--device", "gpu", "--gpus", "0", "--executor", "ray"], ["--gpus 0", "Ray", "drop --gpus"]),
])
@pytest.mark.parametrize("command", ["render", "templates", "dataset"])
def test_gpu_mistakes_on_the_command_line_are_one_line_and_write_nothing(capsys, tmp_path, monkeypatch, command,
                                                                          environ, args, words):
    for name, value in environ.items():
        monkeypatch.setenv(name, value)
    out = tmp_path / "o"
    assert syneepose_cli.main([command, "--out", str(out), *args]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    [line] = err.strip().splitlines()
    for word in words:
        assert word in line, line
    assert not out.exists()


def test_ray_gives_each_gpu_task_one_gpu_and_refuses_a_cluster_without(tmp_path):
    """Ray is told it has two GPUs (it schedules declared GPUs as found ones) and pins each task to one."""
    import ray

    def note_gpu(path):
        time.sleep(0.5)
        Path(path).write_text(os.environ.get(CUDA, "unset"))

    jobs = [str(tmp_path / f"{i}.txt") for i in range(4)]
    ray.init(num_cpus=2, num_gpus=2, include_dashboard=False, log_to_driver=False)
    try:
        run_ray(note_gpu, jobs, None, lambda job: None, gpus=1)
    finally:
        ray.shutdown()
    assert {Path(j).read_text() for j in jobs} <= {"0", "1"}
    ray.init(num_cpus=1, num_gpus=0, include_dashboard=False, log_to_driver=False)
    try:
        with pytest.raises(UserError, match="--device gpu: the Ray cluster has no GPU"):
            run_ray(note_gpu, jobs[:1], None, lambda job: None, gpus=1)
    finally:
        ray.shutdown()
