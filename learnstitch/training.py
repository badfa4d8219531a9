"""Training: ``learnstitch train --config configs/stitch/NAME.yaml [--out DIR] [--resume]``.

One run writes, in its output folder::

    checkpoint.pt     the latest state (model, Adam, step, config, RNG), written atomically every
                      ``checkpoint_every`` steps and at the end; ``--resume`` continues from it
    model.pt          the final weights and config only (what ``evaluate`` and ``stitch`` need)
    metrics.jsonl     one JSON line per ``log_every`` steps: loss and its terms, seconds per step
    tensorboard/      the same scalars, and the sample panoramas, for TensorBoard
    samples/          step_NNNNNN.png every ``image_every`` steps: prediction, truth, |error| x 4
    validation.jsonl  with ``validate_every``: validation PSNR over seen pixels, as configured and
                      clean, gain on and off (:mod:`learnstitch.curves`)
    learning_curves.png  the loss and those curves, redrawn at each validation

Determinism: the model's initial weights come from ``train.seed``; the order of the samples in
epoch ``e`` is a permutation drawn from ``(seed, e)``; the data are deterministic per sample. A
resumed run therefore repeats exactly the steps an uninterrupted run takes, and ends with the
same weights bit for bit (on the same device and thread count).

Data parallel: under ``torchrun --nproc_per_node N`` each process takes ``batch_size / N`` items
of every batch (gloo on CPU, NCCL on CUDA); DistributedDataParallel averages the gradients, so N
processes take the same steps as one process with the whole batch, up to rounding.

Checkpoints hold tensors and plain Python values only and are read with
``torch.load(weights_only=True)``: a checkpoint file can never run code.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import statistics
import time
from pathlib import Path
from typing import NamedTuple

import torch
import torch.distributed as dist
from torch.utils.data import DataLoader, Dataset, Sampler

from rigjax.errors import ConfigError

from .baselines import psnr
from .checkpoint import CHECKPOINT_FORMAT, config_differences, load_checkpoint, save_checkpoint
from .config import StitchConfig, TrainConfig, config_as_dict, config_from_dict
from .data.datasets import collate_rigs
from .data.store import write_png
from .network import build_model
from .network.losses import StitchLoss
from .network.model import ModelConfig, StitchOutput


class TrainingError(RuntimeError):
    """Training cannot go on (a NaN loss, say); the last checkpoint on disk is intact."""


class TrainReport(NamedTuple):
    steps: int  # steps taken in this call
    final_step: int
    seconds: float
    last_loss: float
    out: Path


# Settings that change neither the weights nor the order of the steps: a run may resume with new ones.
_RESUMABLE_KEYS = {
    "train.checkpoint_every",
    "train.log_every",
    "train.image_every",
    "train.tensorboard",
    "train.loader_workers",
    "train.synth_workers",
    "train.data_dir",
    "train.device",
    "train.validate_every",
    "train.validate_samples",
}


def learning_rate(t: TrainConfig, step: int, total: int) -> float:
    """The learning rate of step ``step`` (0-based) of ``total``: a function of the step alone, so a
    resumed run needs no scheduler state."""
    if t.lr_schedule == "constant":
        return t.lr
    return t.lr * 0.5 * (1.0 + math.cos(math.pi * step / total))


def resolve_device(name: str, local_rank: int = 0) -> torch.device:
    """``train.device`` as a torch device: ``auto`` is CUDA where there is one; a CUDA device named
    without an index is this process's (``local_rank``), which ``torch.cuda.set_device`` needs."""
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    try:
        device = torch.device(name)
    except RuntimeError:
        raise ConfigError(f"train.device: not a torch device: {name!r}") from None
    return torch.device("cuda", local_rank) if device.type == "cuda" and device.index is None else device


class _Distributed(NamedTuple):
    rank: int
    world: int
    local_rank: int

    @classmethod
    def from_env(cls) -> _Distributed:
        world = int(os.environ.get("WORLD_SIZE", "1"))
        return cls(int(os.environ.get("RANK", "0")), world, int(os.environ.get("LOCAL_RANK", "0")))


class _StepBatches(Sampler):
    """The indices each step of this process reads, from ``first_step`` to the end of training."""

    def __init__(self, length: int, batch: int, seed: int, first_step: int, steps: int, rank: int, world: int):
        self.length, self.batch, self.seed = length, batch, seed
        self.first_step, self.steps, self.rank, self.world = first_step, steps, rank, world
        self.per_epoch = length // batch

    def order(self, epoch: int) -> torch.Tensor:
        return torch.randperm(self.length, generator=torch.Generator().manual_seed(self.seed * 1_000_003 + epoch))

    def __iter__(self):
        epoch, order = -1, None
        share = self.batch // self.world
        for step in range(self.first_step, self.steps):
            e, i = divmod(step, self.per_epoch)
            if e != epoch:
                epoch, order = e, self.order(e)
            start = i * self.batch + self.rank * share
            yield order[start : start + share].tolist()

    def __len__(self) -> int:
        return self.steps - self.first_step


def training_dataset(config: StitchConfig, *, progress: bool = True, rank: int = 0) -> Dataset:
    """The training samples of ``config``: from ``train.data_dir`` (rendered there first, by
    process 0, when fewer than ``train.samples`` are on disk) or rendered on the fly."""
    from .data.datasets import FolderDataset, GeneratedDataset
    from .data.generate import synthesise

    t = config.train
    if t.data_dir is None:
        return GeneratedDataset(config.data, "train", t.samples, inputs=config.model.inputs)
    if rank == 0:
        synthesise(
            config.data,
            t.data_dir,
            split="train",
            num=t.samples,
            workers=t.synth_workers,
            config_name=config.name,
            progress=progress,
        )
    if dist.is_initialized():
        dist.barrier()
    dataset = FolderDataset(t.data_dir, "train", inputs=config.model.inputs)
    if len(dataset) < t.samples:
        raise ConfigError(f"{t.data_dir}: {len(dataset)} training samples, train.samples asks for {t.samples}")
    return torch.utils.data.Subset(dataset, range(t.samples))


@dataclasses.dataclass
class RunState:
    """One process's run between steps: what ``checkpoint.pt`` holds (with torch's RNG) and what
    :func:`train_step` changes."""

    config: StitchConfig
    model: torch.nn.Module
    optimiser: torch.optim.Optimizer
    device: torch.device
    step: int = 0  # steps taken


class StepResult(NamedTuple):
    """What :func:`train_step` returns: the network's output, the loss and its terms (0-d tensors,
    averaged over the processes) and the learning rate the step took."""

    output: StitchOutput
    losses: dict[str, torch.Tensor]  # "loss", then the terms of StitchLoss
    lr: float


def train(
    config: StitchConfig,
    out: str | Path,
    *,
    resume: bool = False,
    dataset: Dataset | None = None,
    progress: bool = True,
) -> TrainReport:
    """Train ``config``'s network, writing to ``out`` (see the module docstring).

    ``dataset`` replaces the config's training data (items as :mod:`learnstitch.data.datasets` returns
    them). Raises :class:`TrainingError` when the loss stops being finite; the last checkpoint
    written before that is intact.
    """
    from tqdm import tqdm

    t, out = config.train, Path(out)
    proc, device, owns_group = _join_processes(t)
    lead = proc.rank == 0
    checkpoint = _run_folder(out, resume)
    torch.manual_seed(t.seed)
    model = build_model(config.model, config.data).to(device)
    run = RunState(config, model, torch.optim.Adam(model.parameters(), lr=t.lr), device)
    restore(run, checkpoint, resume=resume, announce=progress and lead)
    m = config.model
    loss_fn = StitchLoss(config.loss, max_inverse_depth=m.max_inverse_depth, depth_planes=m.depth_planes).to(device)
    net = torch.nn.parallel.DistributedDataParallel(model) if proc.world > 1 else model
    data = dataset if dataset is not None else training_dataset(config, progress=progress and lead, rank=proc.rank)
    loader, per_epoch, total = make_loader(data, t, run.step, device, rank=proc.rank, world=proc.world)
    log = _Log(out, t, run.step, enabled=lead)
    validation = _Validation(config, out, run.step, enabled=lead)
    first, started, last_loss = run.step, time.perf_counter(), float("nan")
    bar = tqdm(total=total, initial=run.step, desc=f"train {config.name}", unit="step", disable=not (progress and lead))
    try:
        for batch in loader:
            result = train_step(run, net, loss_fn, batch, total=total, world=proc.world, checkpoint=checkpoint)
            bar.update()
            losses = torch.stack(list(result.losses.values())).tolist()  # one wait for the device, not one a term
            values = dict(zip(result.losses, losses), lr=result.lr)
            last_loss = values["loss"]
            log.step(run.step, (run.step - 1) // per_epoch, values, result.output, batch["pano"])
            validation(model, run.step, run.step == total, device)
            if lead and (run.step % t.checkpoint_every == 0 or run.step == total):
                save_run(checkpoint, run, resumable=True)
        if lead:
            save_run(out / "model.pt", run, resumable=False)
    finally:
        bar.close()
        log.close()
        validation.close()
        if owns_group:
            dist.destroy_process_group()
    return TrainReport(run.step - first, run.step, time.perf_counter() - started, last_loss, out)


def _join_processes(t: TrainConfig) -> tuple[_Distributed, torch.device, bool]:
    """This process's place among ``torchrun``'s, its device, and whether it started the process
    group (and so destroys it at the end)."""
    proc = _Distributed.from_env()
    device = resolve_device(t.device, proc.local_rank)
    if t.batch_size % proc.world:
        raise ConfigError(f"train.batch_size {t.batch_size} is not divisible by the {proc.world} processes")
    owns_group = proc.world > 1 and not dist.is_initialized()
    if owns_group:
        dist.init_process_group("nccl" if device.type == "cuda" else "gloo")
    if device.type == "cuda":
        torch.cuda.set_device(device)
    return proc, device, owns_group


def _run_folder(out: Path, resume: bool) -> Path:
    """``out`` made, and its ``checkpoint.pt``; a :class:`ConfigError` where a run is there and
    ``resume`` is false."""
    out.mkdir(parents=True, exist_ok=True)
    checkpoint = out / "checkpoint.pt"
    if checkpoint.exists() and not resume:
        raise ConfigError(
            f"{out} already holds a run ({checkpoint.name}): pass --resume to continue it, or choose another --out"
        )
    return checkpoint


def restore(run: RunState, checkpoint: Path, *, resume: bool, announce: bool = False) -> None:
    """Where ``resume`` and ``checkpoint`` exists, continue it: ``run``'s model, Adam, step and
    torch's RNG as it wrote them (a :class:`ConfigError` where another config wrote it, or it cannot
    be read); otherwise, with ``train.init_from``, start from that checkpoint's weights
    (:func:`_initialise_from`; ``announce`` prints how many)."""
    t = run.config.train
    if resume and checkpoint.exists():
        _resume(run, checkpoint)
    elif t.init_from is not None:
        shared = _initialise_from(run.model, t.init_from)
        if announce:
            print(f"train.init_from: {shared} of {len(run.model.state_dict())} weights from {t.init_from}")


def _resume(run: RunState, checkpoint: Path) -> None:
    state = load_checkpoint(checkpoint)
    if not isinstance(state.get("config"), dict):
        raise ConfigError(f"{checkpoint}: cannot resume from it: it holds no config")
    saved = config_as_dict(config_from_dict(state["config"], str(checkpoint)))
    differ = [k for k in config_differences(config_as_dict(run.config), saved) if k not in _RESUMABLE_KEYS]
    if differ:
        raise ConfigError(f"{checkpoint} was written by another config; these keys differ: {differ}")
    try:
        run.model.load_state_dict(state["model"])
        run.optimiser.load_state_dict(state["optimiser"])
        torch.set_rng_state(state["rng"])
        step = state["step"]
        if not isinstance(step, int) or step < 0:
            raise TypeError(f"step {step!r} is not a step number")
    except (KeyError, RuntimeError, TypeError, ValueError) as error:
        reason = str(error).strip().splitlines()[0] if str(error).strip() else ""
        raise ConfigError(f"{checkpoint}: cannot resume from it ({type(error).__name__}: {reason})") from None
    run.step = step


def save_run(path: Path, run: RunState, *, resumable: bool) -> None:
    """Write ``run`` to ``path`` atomically (:func:`save_checkpoint`): the config, the step and the
    weights; with ``resumable``, also Adam's state and torch's RNG (``checkpoint.pt``, which
    ``--resume`` continues; without, ``model.pt``)."""
    state = {
        "format": CHECKPOINT_FORMAT,
        "config": config_as_dict(run.config),
        "step": run.step,
        "model": run.model.state_dict(),
    }
    if resumable:
        state |= {"optimiser": run.optimiser.state_dict(), "rng": torch.get_rng_state()}
    save_checkpoint(path, state)


def make_loader(
    data: Dataset, t: TrainConfig, first_step: int, device: torch.device, *, rank: int = 0, world: int = 1
) -> tuple[DataLoader, int, int]:
    """The batches of this process (of ``world``) from step ``first_step`` to the end of training
    (:class:`_StepBatches`), the steps per epoch, and the steps of the whole run."""
    per_epoch = len(data) // t.batch_size
    if per_epoch == 0:
        raise ConfigError(f"{len(data)} training samples are fewer than one batch of {t.batch_size}")
    total = t.epochs * per_epoch
    loader = DataLoader(
        data,
        batch_sampler=_StepBatches(len(data), t.batch_size, t.seed, first_step, total, rank, world),
        collate_fn=collate_rigs,
        num_workers=t.loader_workers,
        pin_memory=device.type == "cuda",
        multiprocessing_context="spawn" if t.loader_workers else None,
    )
    return loader, per_epoch, total


def train_step(
    run: RunState,
    net: torch.nn.Module,
    loss_fn: StitchLoss,
    batch: dict[str, torch.Tensor],
    *,
    total: int,
    world: int = 1,
    checkpoint: Path | None = None,
) -> StepResult:
    """Step ``run.step`` of ``total`` on ``batch`` (:func:`collate_rigs`'s): the forward pass of
    ``net`` (``run.model``, or its DistributedDataParallel wrapper), the loss, the gradients (clipped
    to ``train.grad_clip``), the loss and its terms averaged over the ``world`` processes, and Adam's
    step at :func:`learning_rate`; ``run.step`` counts it. A non-finite loss raises
    :class:`TrainingError` before the weights change (naming ``checkpoint``, the last good state)."""
    t, loss_config, device = run.config.train, run.config.loss, run.device
    inputs, masks, centres = (batch[k].to(device, non_blocking=True) for k in ("inputs", "masks", "centres"))
    truth = {k: batch[k].to(device, non_blocking=True) for k in ("pano", "inverse_depth")}
    # The plane and class losses' inputs, from the rig-aware network only.
    planes = loss_config.plane_weight > 0 or loss_config.class_weight > 0
    asked = {"planes": True, "colours": loss_config.plane_weight > 0} if planes else {}
    with torch.autocast(device.type, dtype=torch.bfloat16, enabled=t.amp and device.type == "cuda"):
        output = net(inputs, masks, centres=centres, **asked)
    loss, terms = loss_fn(output, truth)
    run.optimiser.zero_grad(set_to_none=True)
    loss.backward()
    if t.grad_clip > 0:
        torch.nn.utils.clip_grad_norm_(run.model.parameters(), t.grad_clip)
    reduced = torch.stack([loss.detach()] + [v.detach() for v in terms.values()])
    if world > 1:
        dist.all_reduce(reduced)
        reduced /= world
    if not torch.isfinite(reduced[0]):
        raise _nan_error(run, reduced[0], checkpoint)
    lr = learning_rate(t, run.step, total)
    for group in run.optimiser.param_groups:
        group["lr"] = lr
    run.optimiser.step()
    run.step += 1
    return StepResult(output, dict(zip(["loss", *terms], reduced)), lr)


def _nan_error(run: RunState, loss: torch.Tensor, checkpoint: Path | None) -> TrainingError:
    every = run.config.train.checkpoint_every
    kept = (
        f"{checkpoint} (the last good state) is intact"
        if checkpoint is not None and checkpoint.exists()
        else f"no checkpoint had been written yet (train.checkpoint_every is {every})"
    )
    return TrainingError(
        f"step {run.step + 1}: the loss is {loss.item()}; stopped before updating the weights. "
        f"{kept}; a lower train.lr or a train.grad_clip in a new run avoids this"
    )


def _initialise_from(model: torch.nn.Module, path: str) -> int:
    """Copy into ``model`` the weights of checkpoint ``path`` whose names and shapes match its
    own; returns how many. When the checkpoint's network is this one without some of its cues
    (:data:`_CUES`, which join channels to the end of the decoder's extra input), the decoder's
    convolutions that read more channels here take the checkpoint's weights for the channels it had
    and zeros for the new ones, so that the run starts as the checkpoint's function. A checkpoint
    that shares none is a :class:`ConfigError` naming ``train.init_from`` (an unreadable one names
    the file, :func:`load_checkpoint`)."""
    state = load_checkpoint(path)
    theirs, mine = state["model"], model.state_dict()
    widen = _same_but_cues(state.get("config"), model.config)
    shared = {}
    for name, value in theirs.items():
        own = mine.get(name)
        if own is None:
            continue
        if own.shape == value.shape:
            shared[name] = value
        elif widen and own.ndim == 4 and own.shape[0] == value.shape[0] and own.shape[1] > value.shape[1]:
            # Zeros beside the checkpoint's weights (on the CPU): the model may already sit on a GPU.
            shared[name] = torch.cat(
                [value, value.new_zeros(own.shape[0], own.shape[1] - value.shape[1], *own.shape[2:])], 1
            )
    if not shared:
        raise ConfigError(f"train.init_from: {path} shares no weight (name and shape) with this model")
    model.load_state_dict(shared, strict=False)
    return len(shared)


# Model options that only join maps to the decoder's extra input, after those it had; and those that
# act at inference only, which no weight depends on.
_CUES = ("ghost_cost", "first_surface")
_INFERENCE_ONLY = {"surface_rule": 0.0, "surface_grow": 0}


def _same_but_cues(saved: dict | None, mine: ModelConfig) -> bool:
    """Whether a checkpoint's config (``saved``, as written) has the model ``mine`` but for cues
    that ``mine`` adds and options that act at inference only."""
    try:
        theirs = config_from_dict(saved or {}, "checkpoint").model
    except ConfigError:
        return False
    plain = {**{key: False for key in _CUES}, **_INFERENCE_ONLY}
    added = all(getattr(mine, key) or not getattr(theirs, key) for key in _CUES)
    return added and dataclasses.replace(theirs, **plain) == dataclasses.replace(mine, **plain)


class _Log:
    """metrics.jsonl, TensorBoard and sample images (process 0 only)."""

    def __init__(self, out: Path, t: TrainConfig, step: int, enabled: bool):
        self.out, self.t, self.enabled = out, t, enabled
        self.last = time.perf_counter()
        self.writer = None
        if not enabled:
            return
        self.jsonl = _open_log(out / "metrics.jsonl", step)
        if t.tensorboard:
            try:
                from torch.utils.tensorboard import SummaryWriter
            except ImportError:
                raise ConfigError(
                    "train.tensorboard is true but the tensorboard package is not installed "
                    "(pip install tensorboard, or set train.tensorboard: false)"
                ) from None
            self.writer = SummaryWriter(str(out / "tensorboard"), purge_step=step + 1 if step else None)

    def step(self, step: int, epoch: int, values: dict[str, float], output, target) -> None:
        if not self.enabled:
            return
        if step % self.t.log_every == 0:
            now = time.perf_counter()
            record = {"step": step, "epoch": epoch, **values, "seconds_per_step": (now - self.last) / self.t.log_every}
            self.last = now
            self.jsonl.write(json.dumps(record) + "\n")
            self.jsonl.flush()
            if self.writer is not None:
                for key, value in values.items():
                    self.writer.add_scalar(f"train/{key}", value, step)
        if step % self.t.image_every == 0:
            image = sample_strip(output.pano[0].detach().float(), target[0].float())
            (self.out / "samples").mkdir(exist_ok=True)
            write_png(self.out / "samples" / f"step_{step:06d}.png", image)
            if self.writer is not None:
                self.writer.add_image("train/prediction_truth_error", image, step)

    def close(self) -> None:
        if self.enabled:
            self.jsonl.close()
            if self.writer is not None:
                self.writer.close()


def _open_log(path: Path, step: int):
    """``path`` opened for appending, without the lines a killed run wrote after its last checkpoint
    at ``step`` (and a line cut short): the resumed run writes them again."""
    if path.exists():
        kept = [line for line in path.read_text().splitlines() if _logged_step(line) <= step]
        tmp = path.with_name(f".{path.name}.partial")
        tmp.write_text("".join(line + "\n" for line in kept))
        os.replace(tmp, path)
    return path.open("a")


class _Validation:
    """PSNR over the seen pixels of ``validate_samples`` validation samples (seeds never trained on
    or tested), rendered as configured and photometrically clean, with the network's colour
    correction on and off, every ``validate_every`` steps: ``validation.jsonl`` and
    ``learning_curves.png``."""

    def __init__(self, config: StitchConfig, out: Path, step: int, enabled: bool):
        self.every = config.train.validate_every
        self.enabled = enabled and self.every > 0
        if not self.enabled:
            return
        from .baselines import rotation_only_stitch
        from .data.sample import nominal_unwarp_grids
        from .data.store import SPLIT_SEED_BASE
        from .evaluation import CLEAN_PHOTOMETRY, data_with, prepare_sample

        # Random rigs are validated on the three-fisheye rig their config describes (one of their cases).
        rig = data_with(config.data, {"rig": "tri"})
        grids, masks, _ = nominal_unwarp_grids(rig)
        seeds = range(SPLIT_SEED_BASE["validation"], SPLIT_SEED_BASE["validation"] + config.train.validate_samples)
        self.sets, self.rotation_only = {}, {}
        for name, data in (("configured", rig), ("clean", data_with(rig, CLEAN_PHOTOMETRY))):
            tests = [prepare_sample(data, seed, grids, masks, config.model.inputs) for seed in seeds]
            self.sets[name] = tests
            self.rotation_only[name] = statistics.fmean(
                float(
                    psnr(
                        rotation_only_stitch(t.sample.fisheyes, t.sample.rig, data)[0], t.sample.pano, t.regions["seen"]
                    )
                )
                for t in tests
            )
        self.out = out
        self.jsonl = _open_log(out / "validation.jsonl", step)

    def __call__(self, model: torch.nn.Module, step: int, last: bool, device: torch.device) -> None:
        if not self.enabled or (step % self.every and not last):
            return
        from .curves import plot_learning_curves
        from .evaluation import network_panos

        was_training = model.training
        model.eval()
        record = {"step": step}
        for name, tests in self.sets.items():
            scores: dict[str, list[float]] = {}
            for test in tests:
                for method, pano in network_panos(model, test, device).items():
                    scores.setdefault(method, []).append(float(psnr(pano, test.sample.pano, test.regions["seen"])))
            record[name] = {m: statistics.fmean(v) for m, v in scores.items()} | {
                "rotation_only": self.rotation_only[name]
            }
        model.train(was_training)
        self.jsonl.write(json.dumps(record) + "\n")
        self.jsonl.flush()
        plot_learning_curves({self.out.name: self.out}, self.out / "learning_curves.png")

    def close(self) -> None:
        if self.enabled:
            self.jsonl.close()


def _logged_step(line: str) -> float:
    try:
        return json.loads(line)["step"]
    except (json.JSONDecodeError, KeyError, TypeError):
        return math.inf


def sample_strip(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """``(3, 3 H, W)``: prediction, truth and four times the absolute error, stacked."""
    pred = pred.clamp(0.0, 1.0).cpu()
    target = target.cpu()
    return torch.cat([pred, target, ((pred - target).abs() * 4.0).clamp(0.0, 1.0)], dim=1)
