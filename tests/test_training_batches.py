"""Batches prepared ahead of the step: the same batches with and without workers, exact resume,
errors from workers, the data-wait split and warning, bfloat16 and compiled networks."""

import csv
import math
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest
import torch
from training_helpers import tiny_config

from datasets import JointAugment
from models.training import BatchStream, DataWaitWarning, StepTimer, Trainer, auto_workers
from models.training.sampling import StepSampler
from models.training.step_timing import JUDGED_AFTER, WARMUP_STEPS

ROOT = Path(__file__).resolve().parents[1]


class _Augmented(torch.utils.data.Dataset):
    """Samples with random crops, flips and gains from torch's global generator."""

    def __init__(self, scenes):
        self.scenes = scenes
        self.augment = JointAugment(crop_size=(12, 12), hflip=0.5, gain=0.1)

    def __len__(self):
        return len(self.scenes)

    def __getitem__(self, index):
        return self.augment(dict(self.scenes[index]))


@pytest.fixture(scope="module")
def augmented(scenes):
    return _Augmented(scenes)


def _losses(history):
    return [row["loss"] for row in history]


def test_workers_give_the_same_batches_as_the_loop(augmented):
    sampler = StepSampler(augmented, batch_size=3, seed=5)
    device = torch.device("cpu")
    with BatchStream(sampler, 2, 6, device, workers=0) as stream:
        inline = [batch for batch, _ in stream]
    with BatchStream(sampler, 2, 6, device, workers=2) as stream:
        ahead = [batch for batch, _ in stream]
    assert len(inline) == len(ahead) == 4
    for a, b in zip(inline, ahead, strict=True):
        assert a["id"] == b["id"]
        for key in ("image", "focused", "depth", "mask"):
            assert torch.equal(a[key], b[key]), key
    # the samples' random crops differ between steps: the seeds are per step and position
    assert not torch.equal(inline[0]["image"], inline[1]["image"])


@pytest.mark.parametrize("workers", [0, 2])
def test_the_device_thread_gives_the_same_batches(augmented, workers):
    """`device_thread` moves the batches in a thread (on a GPU, on a side stream): same batches,
    same order, and the stream ends where the loop's does."""
    sampler = StepSampler(augmented, batch_size=3, seed=5)
    device = torch.device("cpu")
    with BatchStream(sampler, 1, 5, device, workers=0) as stream:
        inline = [batch for batch, _ in stream]
    with BatchStream(sampler, 1, 5, device, workers=workers, device_thread=True) as stream:
        moved = [batch for batch, _ in stream]
        with pytest.raises(StopIteration):  # and again after the end
            next(stream)
    assert [b["id"] for b in moved] == [b["id"] for b in inline]
    for a, b in zip(inline, moved, strict=True):
        assert torch.equal(a["image"], b["image"])
        assert torch.equal(a["camera"].focus_distance, b["camera"].focus_distance)


def test_the_device_thread_raises_a_worker_error_where_the_batch_is_taken(scenes):
    broken = _Hooked(scenes, _missing_file_at(1))
    sampler = StepSampler(broken, batch_size=2, seed=0)
    with BatchStream(sampler, 0, 4, torch.device("cpu"), workers=1, device_thread=True) as stream:
        with pytest.raises(FileNotFoundError, match="scene 1: missing file"):
            for _ in stream:
                pass


def test_closing_the_stream_stops_the_device_thread(augmented):
    sampler = StepSampler(augmented, batch_size=2, seed=0)
    stream = BatchStream(sampler, 0, 50, torch.device("cpu"), workers=1, device_thread=True)
    next(stream)
    thread = stream._mover.thread
    stream.close()
    assert not thread.is_alive()


def test_closing_the_stream_stops_its_workers_even_if_the_iterator_lives_on(augmented):
    """A reference that outlives `close` (as an exception's traceback may hold) must not keep
    workers alive: they ignore SIGTERM, and would hold up the process's exit."""
    sampler = StepSampler(augmented, batch_size=2, seed=0)
    stream = BatchStream(sampler, 0, 50, torch.device("cpu"), workers=2)
    next(stream)
    kept = stream._iterator
    workers = list(kept._workers)
    stream.close()
    assert workers and not any(w.is_alive() for w in workers)


def test_a_gpu_stream_moves_batches_in_a_thread_only_with_workers():
    sampler = StepSampler([{"image": torch.zeros(3, 2, 2)}] * 2, batch_size=1, seed=0)
    cuda = torch.device("cuda")
    assert BatchStream(sampler, 0, 1, cuda, workers=2).device_thread
    assert not BatchStream(sampler, 0, 1, cuda, workers=0).device_thread
    assert not BatchStream(sampler, 0, 1, torch.device("cpu"), workers=2).device_thread


def test_moving_a_batch_to_the_device_reads_no_values(augmented, monkeypatch):
    """The batch was checked where it was prepared: moving it (camera settings included) runs
    no value check, which on a GPU would wait for the device's queue each step."""
    from optics import CameraSettings

    sampler = StepSampler(augmented, batch_size=3, seed=5)
    with BatchStream(sampler, 0, 2, torch.device("cpu"), workers=0) as stream:
        batch = stream.batches.batch(0)
        assert isinstance(batch["camera"], CameraSettings)

        def refuse(self):
            raise AssertionError("a value check while moving the batch")

        monkeypatch.setattr(stream.batches, "batch", lambda step: batch)  # prepared already
        monkeypatch.setattr(CameraSettings, "check", refuse)
        moved, _ = next(stream)
    assert isinstance(moved["camera"], CameraSettings)
    assert torch.equal(moved["camera"].focus_distance, batch["camera"].focus_distance)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="pinned memory needs CUDA")
def test_camera_settings_pin_and_move_without_waiting():
    from optics import CameraSettings

    pinned = CameraSettings(0.05, 2.0, [[2.0, 6.0]], 1e-5).pin_memory()
    assert all(t.is_pinned() for t in pinned.tensors().values())
    moved = pinned.to("cuda", non_blocking=True)
    assert moved.focus_distance.is_cuda


def test_sample_randomness_leaves_the_global_generator_alone(augmented):
    torch.manual_seed(123)
    expected = torch.rand(3)
    torch.manual_seed(123)
    StepSampler(augmented, batch_size=2, seed=0).samples(0)
    assert torch.equal(torch.rand(3), expected)


def test_training_with_workers_equals_training_without(tmp_path, augmented):
    inline = Trainer(tiny_config(tmp_path / "inline", workers=0), augmented).fit()
    ahead = Trainer(tiny_config(tmp_path / "ahead", workers=2), augmented).fit()
    assert _losses(inline) == _losses(ahead)


def test_resume_with_workers_is_exact(tmp_path, augmented):
    full = Trainer(tiny_config(tmp_path / "full", workers=1), augmented).fit()
    cfg = tiny_config(tmp_path / "split", workers=1)
    Trainer(cfg, augmented).fit(until=2)
    resumed = Trainer(cfg, augmented)  # a new process would start its workers afresh too
    assert resumed.step == 2
    assert _losses(resumed.fit()) == _losses(full)


class _Hooked(torch.utils.data.Dataset):
    """The scenes, with `before(index)` called before each is read."""

    def __init__(self, scenes, before):
        self.scenes, self.before = scenes, before

    def __len__(self):
        return len(self.scenes)

    def __getitem__(self, index):
        self.before(index)
        return self.scenes[index]


def _missing_file_at(bad_index):
    def before(index):
        if index == bad_index:
            raise FileNotFoundError(f"scene {index}: missing file 'x.png'")
    return before


@pytest.mark.parametrize("workers", [0, 1])
def test_a_worker_error_arrives_with_its_type_and_words(tmp_path, scenes, workers):
    broken = _Hooked(scenes, _missing_file_at(4))
    trainer = Trainer(tiny_config(tmp_path / "run", workers=workers, steps=3), broken)
    with pytest.raises(FileNotFoundError, match="scene 4: missing file 'x.png'"):
        trainer.fit()


def test_bad_depth_is_named_from_a_worker(tmp_path, scenes):
    bad = [dict(scenes[i]) for i in range(4)]
    bad[2]["depth"] = bad[2]["depth"].clone()
    bad[2]["depth"][0, 3, 3] = float("nan")
    trainer = Trainer(tiny_config(tmp_path / "run", supervision="depth", workers=1, batch_size=4,
                                  steps=1), bad)
    with pytest.raises(ValueError, match=r"sample '.*' \(train_set\[2\]\) has ground-truth depth"):
        trainer.fit()


def test_each_step_is_split_into_data_wait_and_compute(tmp_path, scenes):
    cfg = tiny_config(tmp_path / "run", workers=0)
    history = Trainer(cfg, scenes).fit()
    for row in history:
        assert row["data_s"] >= 0 and row["compute_s"] > 0
        assert row["data_s"] + row["compute_s"] <= row["seconds"] + 1e-6
    with (cfg.out_dir / "train_log.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    phases = {"network_s", "loss_s", "backward_s", "optimizer_s"}
    assert {"data_s", "compute_s"} | phases <= set(rows[0]) and len(rows) == 4
    for row in history:  # the phases are timed inside the compute, one after the other
        assert all(row[name] > 0 for name in phases)
        assert sum(row[name] for name in phases) <= row["compute_s"] + 1e-6


def test_step_timer_splits_the_mean_step_into_its_phases():
    timer = StepTimer()
    assert timer.split() == {} and timer.summary() == ""
    timer.add(data_s=9.0, compute_s=9.0, phases={"network": 9.0})  # warm-up: left out
    timer.add(data_s=9.0, compute_s=9.0, phases={"network": 9.0})
    for network in (0.2, 0.3):
        timer.add(data_s=0.01, compute_s=1.0,
                  phases={"network": network, "loss": 0.1, "backward": 0.5, "optimizer": 0.05})
    split = timer.split()
    assert list(split) == ["step", "data", "network", "loss", "backward", "optimizer", "other"]
    assert split["step"] == pytest.approx(1.01) and split["network"] == pytest.approx(0.25)
    assert split["other"] == pytest.approx(0.1)  # 1.0 - 0.25 - 0.1 - 0.5 - 0.05
    assert sum(v for k, v in split.items() if k != "step") == pytest.approx(split["step"])
    assert timer.summary() == ("step 1.01 s: data 10 ms, network 250 ms, loss 100 ms, "
                               "backward 500 ms, optimizer 50 ms, other 100 ms (mean of 2 steps)")


def test_auto_precision_is_bfloat16_only_on_a_cpu_with_native_bfloat16(monkeypatch):
    from models.training.forward import network_precision

    cpu, gpu = torch.device("cpu"), torch.device("cuda")
    assert network_precision("float32", cpu) == "float32"
    assert network_precision("bfloat16", gpu) == "bfloat16"
    assert network_precision("auto", gpu) == "float32"
    for native, expected in ((True, "bfloat16"), (False, "float32")):
        monkeypatch.setattr(torch.ops.mkldnn, "_is_mkldnn_bf16_supported", lambda n=native: n)
        assert network_precision("auto", cpu) == expected


def test_a_step_that_waits_for_its_data_warns(tmp_path, scenes, monkeypatch):
    """Each batch arrives after a (simulated) second: the run warns once, in warnings.log too."""
    arrive = BatchStream.__next__
    monkeypatch.setattr(BatchStream, "__next__", lambda self: (arrive(self)[0], 1.0))
    steps = WARMUP_STEPS + JUDGED_AFTER
    trainer = Trainer(tiny_config(tmp_path / "run", workers=0, steps=steps, batch_size=1,
                                  supervision="depth"), scenes)
    with pytest.warns(DataWaitWarning, match=r"waiting for data took \d+% .*workers=0 now"):
        trainer.fit()
    assert len(trainer.warnings) == 1
    assert "waiting for data" in (tmp_path / "run" / "warnings.log").read_text()
    assert all(row["data_s"] == 1.0 for row in trainer.history)


def test_step_timer_judges_after_the_warm_up():
    timer = StepTimer()
    for _ in range(WARMUP_STEPS):
        timer.add(data_s=5.0, compute_s=0.1)  # start-up: left out
    for _ in range(JUDGED_AFTER - 1):
        timer.add(data_s=0.01, compute_s=0.09)
    assert timer.wait_message(workers=0) is None  # not yet judged
    timer.add(data_s=0.01, compute_s=0.09)
    assert math.isclose(timer.share(), 0.1)
    assert timer.wait_message(workers=0) is None  # 10 %: fine
    slow = StepTimer()
    for _ in range(WARMUP_STEPS + JUDGED_AFTER):
        slow.add(data_s=0.03, compute_s=0.07)
    assert "30%" in slow.wait_message(workers=2)
    assert slow.wait_message(workers=2) is None  # once


def test_auto_workers():
    assert auto_workers(torch.device("cpu"), cpus=2) == 0
    assert auto_workers(torch.device("cpu"), cpus=64) == 7
    assert auto_workers(torch.device("cuda"), cpus=2) == 1
    assert auto_workers(torch.device("cuda"), cpus=16) == 4


def test_bfloat16_network_trains_with_float32_weights(tmp_path, scenes):
    trainer = Trainer(tiny_config(tmp_path / "run", precision="bfloat16"), scenes)
    history = trainer.fit()
    assert all(math.isfinite(row["loss"]) for row in history)
    assert all(p.dtype == torch.float32 for p in trainer.model.parameters())
    float32 = Trainer(tiny_config(tmp_path / "f32"), scenes).fit()
    assert history[0]["loss"] == pytest.approx(float32[0]["loss"], rel=0.05)


@pytest.mark.slow
def test_compiled_network_and_loss_match_the_eager_ones(tmp_path, scenes):
    """Self-supervised: the network, the renderer and the loss in one compiled graph (no graph
    break: a break would fall back to eager and keep the host-bound step)."""
    pytest.importorskip("torch._inductor")
    from torch._dynamo.utils import counters

    exact = {"steps": 2, "precision": "float32"}  # bfloat16 would round differently
    eager = Trainer(tiny_config(tmp_path / "eager", **exact), scenes).fit()
    torch._dynamo.reset()
    counters.clear()
    compiled = Trainer(tiny_config(tmp_path / "compiled", **exact, compile=True,
                                   compile_mode="reduce-overhead"), scenes).fit()
    assert _losses(compiled) == pytest.approx(_losses(eager), rel=1e-4)
    assert not counters["graph_break"], dict(counters["graph_break"])


@pytest.mark.slow
def test_ctrl_c_with_workers_stops_cleanly_and_resumes(tmp_path):
    """Ctrl-C reaches the whole process group: the workers leave it to the training loop."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
    env.pop("DEFOCUS_DEBUG", None)
    out = tmp_path / "run"
    command = [sys.executable, "-m", "defocus", "train", "--out", str(out), "--scenes", "4",
               "--size", "16", "16", "--set", "steps=300", "batch_size=1", "width=4",
               "progress=false", "supervision=depth", "checkpoint_minutes=0", "workers=1"]
    proc = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    log = out / "train_log.csv"
    deadline = time.monotonic() + 120
    while proc.poll() is None and time.monotonic() < deadline:
        if log.exists() and len(log.read_text().splitlines()) >= 3:
            os.killpg(proc.pid, signal.SIGINT)  # as a terminal sends it: to every process
            break
        time.sleep(0.01)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "interrupted: stopped by SIGINT after step" in err and "Traceback" not in err, err
    resumed = subprocess.run([*command, "--resume"], env=env, capture_output=True, text=True,
                             timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    with log.open() as handle:
        steps = [int(row["step"]) for row in csv.DictReader(handle)]
    assert steps == list(range(1, 301))


def test_no_warnings_from_a_quick_run(tmp_path, scenes):
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWaitWarning)
        Trainer(tiny_config(tmp_path / "run", workers=0), scenes).fit()


def test_precision_and_compile_mode_are_checked_by_name():
    from models.training.config import TrainConfig

    with pytest.raises(ValueError, match=r"compile_mode must be one of .*'reduce-overhead'.*"
                                         r"got 'fast'"):
        TrainConfig(compile_mode="fast")
    with pytest.raises(ValueError, match="precision must be one of"):
        TrainConfig(precision="float16")
    assert TrainConfig(compile=True).override(["compile_mode=reduce-overhead"]).compile_mode \
        == "reduce-overhead"
    with pytest.raises(ValueError, match="compile_mode='reduce-overhead' needs compile=true"):
        TrainConfig(compile_mode="reduce-overhead")
