"""The camera a run learns with its network (`TrainConfig.learn_optics`): built from the
training samples' camera, the focused images of each batch rendered through it, and what the
run keeps of it: the checkpoint's entries, the columns of `train_log.csv`, `camera.json`,
`mask.png` and the figure `optics.png` in the run folder.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from optics import CameraSettings, LearnableCamera, Mask, add_noise
from optics.camera import SETTING_FIELDS

from ..depth_from_photos.trained_network import camera_record
from ..losses import DefocusLoss
from .config import TrainConfig
from .run_log import CsvLog

#: checkpoint key of the learned camera's parameters (`LearnableCamera.state_dict`)
OPTICS_KEY = "optics"
#: checkpoint key of the learned aperture mask's values `(h, w)` in [0, 1] (a plain tensor)
MASK_KEY = "camera_mask"
#: the smallest depth a focused image is rendered at, metres (as `datasets.SynthesizedFocus`)
MIN_RENDER_DEPTH = 1e-3
#: the factor between the network's depth and the neighbours `depth_contrast` renders it
#: against (nearer and farther)
CONTRAST_FACTOR = 1.25


def build_learned_camera(config: TrainConfig, camera: Mapping[str, Sequence[float]] | None,
                         device: torch.device | str = "cpu") -> LearnableCamera | None:
    """The `LearnableCamera` of a run (None when `config.learn_optics` is empty): it starts at
    `camera`, the training samples' (`camera_record` of the first sample), learns what
    `learn_optics` names, keeps the focus distances inside the config's depth range and the
    f-numbers within `f_number_min`, `f_number_max`, and renders with the config's PSF
    (`aperture`) unless it learns the mask, which starts at the open disk with seeded noise of
    `mask_start_noise` on its logits (the disk's light all the same); on `device`.

    Raises:
        ValueError: the samples have no camera, or its values lie outside those limits (named).

    Example:
        >>> cfg = TrainConfig(learn_optics="focus")
        >>> record = {"focal_length": [0.05, 0.05], "f_number": [2.8, 2.8],
        ...           "focus_distance": [2.0, 6.0], "pixel_pitch": [1.8e-4, 1.8e-4]}
        >>> build_learned_camera(cfg, record).learn
        ('focus',)
    """
    if not config.learn_optics:
        return None
    if camera is None:
        raise ValueError(f"learn_optics={config.learn_optics!r} needs the training samples' "
                         "camera (their 'camera' settings), where learning starts")
    settings = CameraSettings(*(camera[name] for name in SETTING_FIELDS),
                              aperture=config.aperture)
    try:
        camera = LearnableCamera(settings, (config.depth_min, config.depth_max),
                                 config.learn_optics.split(","),
                                 (config.f_number_min, config.f_number_max), config.mask_size)
    except ValueError as error:
        raise ValueError(f"learn_optics={config.learn_optics!r}: {error} (depth_range is "
                         "depth_min, depth_max; f_number_range f_number_min, f_number_max)"
                         ) from None
    if camera.mask is not None and config.mask_start_noise > 0:  # the light stays the disk's
        noise = torch.randn(camera.mask.logits.shape, dtype=camera.mask.logits.dtype,
                            generator=torch.Generator().manual_seed(config.seed))
        with torch.no_grad():
            camera.mask.logits.add_(config.mask_start_noise * noise)
    return camera.to(device)


def param_groups(network: nn.Module, camera: LearnableCamera | None,
                 config: TrainConfig) -> Any:
    """What the optimiser optimises: the network's parameters, and the learned camera's in a
    param group of their own (learning rate `optics_lr`, no weight decay)."""
    if camera is None:
        return network.parameters()
    return [{"params": list(network.parameters())},
            {"params": list(camera.parameters()), "lr": config.optics_lr, "weight_decay": 0.0}]


def optics_gradients(camera: LearnableCamera | None, network_norm: Tensor, grad_clip: float,
                     world_size: int = 1) -> Tensor:
    """Prepare the learned camera's gradients for the optimiser step: averaged over the
    `world_size` processes (the camera is outside DDP), clipped to the norm `grad_clip` on
    their own (0: not clipped; the network's norm is no scale for them). Returns the norm of
    all gradients before clipping: the network's (`network_norm`) and theirs."""
    optics = [] if camera is None else [p for p in camera.parameters() if p.grad is not None]
    if not optics:
        return network_norm
    if world_size > 1:
        import torch.distributed as dist

        for p in optics:
            dist.all_reduce(p.grad)
            p.grad /= world_size
    norm = nn.utils.clip_grad_norm_(optics, grad_clip) if grad_clip > 0 else \
        torch.linalg.vector_norm(torch.stack([p.grad.norm() for p in optics]))
    return torch.linalg.vector_norm(torch.stack([network_norm, norm.to(network_norm)]))


def render_batch(camera: LearnableCamera, batch: Mapping[str, Any], config: TrainConfig,
                 generator: torch.Generator | None = None) -> dict[str, Any]:
    """`batch` with its `focused` images `(B, F, 3, H, W)` rendered from its `image` and
    `depth` through `camera` (differentiable in the learned values, with the config's render
    mode and window) with the sensor's noise at the light each shot gathers (`read_noise`,
    `shot_noise`, `LearnableCamera.light`; drawn from `generator`, else the global one),
    and its `camera` entry the learned `(B, F)` settings."""
    image = batch["image"]
    depth = batch["depth"].clamp_min(MIN_RENDER_DEPTH)
    focused = camera.render(image, depth, mode=config.render_mode,
                            max_kernel_size=config.max_kernel_size)
    if config.read_noise or config.shot_noise:
        focused = add_noise(focused, config.read_noise, config.shot_noise,
                            camera.light().to(focused).view(1, -1, 1, 1, 1), generator)
    settings = camera.settings().to(image.dtype).batched(image.shape[0])
    return {**batch, "focused": focused, "camera": settings}


def depth_contrast(loss: DefocusLoss, depth: Tensor, batch: Mapping[str, Any],
                   total: Tensor) -> tuple[Tensor, Tensor]:
    """What `TrainConfig.optics_objective="contrast"` adds to a self-supervised loss `total`
    of the network's `depth` `(B,1,H,W)` metres on a `batch` rendered through a learned camera
    (`image`, `focused`, `camera`).

    The camera lowers `total` with less blur at any depth as well (the photos then match
    whatever the depth); this term makes it lower `log total - log reference` instead, the
    reference being the same loss at the network's depth times and divided by
    `CONTRAST_FACTOR` (the mean of both): photos that tell the network's depth from its
    neighbours. It is `total * (log reference - log reference)` with the first log detached:
    0 in value, no gradient for the network, and for the camera the gradient of that log
    ratio times `total` (a slowly varying scale an Adam step ignores).

    Returns:
        the term (0, to add to the loss) and the contrast, the reference over `total`
        (> 1 where the photos tell the depth from its neighbours; no gradient).

    Example:
        >>> cam = LearnableCamera(CameraSettings(0.05, 2.0, [2.0, 6.0], 1.8e-4), (1.0, 10.0))
        >>> image, depth = torch.rand(1, 3, 16, 16), torch.full((1, 1, 16, 16), 3.0)
        >>> batch = render_batch(cam, {"image": image, "depth": depth}, TrainConfig(read_noise=0,
        ...                      shot_noise=0, learn_optics="focus"))
        >>> total = DefocusLoss()(depth * 1.1, image, batch["focused"], batch["camera"])["loss"]
        >>> term, contrast = depth_contrast(DefocusLoss(), depth * 1.1, batch, total)
        >>> float(term.detach()), bool(contrast > 1)
        (0.0, True)
    """
    reference = sum(loss(depth.detach() * factor, batch["image"], batch["focused"],
                         batch["camera"])["loss"]
                    for factor in (CONTRAST_FACTOR, 1 / CONTRAST_FACTOR)) / 2
    log_reference = reference.log()
    return (total.detach() * (log_reference.detach() - log_reference),
            (reference / total).detach())


def rendered_samples(camera: LearnableCamera | None, samples: Iterable[Mapping[str, Any]],
                     config: TrainConfig) -> Iterable[Mapping[str, Any]]:
    """Unbatched `samples` with their focused images rendered through the current `camera`
    from their image and depth (no gradients), the noise of the `i`-th drawn with seed `i`
    (every network scored on the same draws): what a network trained with it reads when it
    is evaluated (`samples` as they are without a camera)."""
    return samples if camera is None else _rendered(camera, samples, config)


def _rendered(camera: LearnableCamera, samples: Iterable[Mapping[str, Any]],
              config: TrainConfig) -> Iterator[dict[str, Any]]:
    for index, sample in enumerate(samples):
        batch = {"image": sample["image"][None], "depth": sample["depth"][None]}
        device = next(iter(camera.buffers())).device
        with torch.no_grad():
            batch = render_batch(camera, {k: v.to(device) for k, v in batch.items()}, config,
                                 torch.Generator().manual_seed(index))
        yield {**sample, "focused": batch["focused"][0].to(sample["image"].device),
               "camera": batch["camera"][0].to(sample["image"].device)}


def log_columns(camera: LearnableCamera) -> dict[str, float]:
    """The learned camera's values as `train_log.csv` columns: `focus_distance_i` (metres) and
    `f_number_i` per shot (from 1), and for a learned mask `mask_open` (the share of its cells
    above 0.5) and `mask_asymmetry` (its mean difference from itself turned by 180 degrees:
    0 for a symmetric code, which blurs a depth and its mirror alike).

    Example:
        >>> cam = LearnableCamera(CameraSettings(0.05, 2.8, [2.0, 6.0], 1.8e-4), (1.0, 10.0))
        >>> sorted(log_columns(cam))
        ['f_number_1', 'f_number_2', 'focus_distance_1', 'focus_distance_2', 'mask_asymmetry', 'mask_open']
    """
    with torch.no_grad():
        settings = camera.settings()
        columns = {f"focus_distance_{i + 1}": float(v)
                   for i, v in enumerate(settings.focus_distance)}
        columns.update({f"f_number_{i + 1}": float(v) for i, v in enumerate(settings.f_number)})
        if camera.mask is not None:
            mask = camera.mask.values()
            columns["mask_open"] = float((mask > 0.5).double().mean())
            columns["mask_asymmetry"] = float((mask - mask.flip(0, 1)).abs().mean())
    return columns


def checkpoint_entries(camera: LearnableCamera) -> dict[str, Any]:
    """What a checkpoint keeps of the learned camera: its settings as the camera the network
    was trained for (`camera`, a `camera_record`), its parameters (`OPTICS_KEY`, to resume)
    and the mask's values (`MASK_KEY`, to render with it; learned masks only)."""
    with torch.no_grad():
        entries: dict[str, Any] = {"camera": camera_record(camera.settings()), OPTICS_KEY: {
            k: v.detach().cpu().clone() for k, v in camera.state_dict().items()}}
    if camera.mask is not None:
        entries[MASK_KEY] = camera.mask.values().detach().cpu().clone()
    return entries


def restore(camera: LearnableCamera | None, state: Mapping[str, Any]) -> None:
    """Load the learned camera's parameters from a checkpoint's `state` (`OPTICS_KEY`;
    nothing without a camera or where the checkpoint holds none)."""
    if camera is not None and OPTICS_KEY in state:
        camera.load_state_dict(state[OPTICS_KEY])


def starting_camera(state: Mapping[str, Any]) -> dict[str, list[float]] | None:
    """The camera a checkpoint's learned camera started from (the training samples', a
    `camera_record`), from its parameters (`OPTICS_KEY`); None where it holds none."""
    optics = state.get(OPTICS_KEY)
    if not isinstance(optics, Mapping):
        return None
    names = {"focal_length": "focal_length", "f_number": "fixed_f_number",
             "focus_distance": "fixed_focus", "pixel_pitch": "pixel_pitch"}
    return {name: [float(v) for v in optics[key].reshape(-1)] for name, key in names.items()}


def checkpoint_aperture(state: Mapping[str, Any]) -> Mask | None:
    """The learned aperture mask a checkpoint holds (`MASK_KEY`) as a fixed `optics.Mask`,
    or None where the run did not learn one."""
    mask = state.get(MASK_KEY)
    return Mask(mask.detach().cpu().double()) if isinstance(mask, Tensor) else None


def write_camera(camera: LearnableCamera, out_dir: str | Path, step: int) -> list[Path]:
    """Write the learned camera into the run folder: `camera.json` (its `(F,)` settings,
    read back by `optics.CameraSettings.read_json`, with the mask's values, what was learned,
    the limits and `step` as extra entries) and, for a learned mask, `mask.png` (its values,
    black 0 to white 1, one pixel per cell scaled up 16 times). Returns the paths written."""
    out_dir = Path(out_dir)
    record = camera.record()
    extra = {key: record[key] for key in ("mask", "learned", "depth_range", "f_number_range")}
    written = [out_dir / "camera.json"]
    with torch.no_grad():
        camera.settings().to_json(written[0], step=step, **extra)
    if camera.mask is not None:
        import numpy as np
        from PIL import Image

        values = camera.mask.values().detach().cpu().double().numpy()
        pixels = np.kron(np.round(values * 255), np.ones((16, 16))).astype(np.uint8)
        written.append(out_dir / "mask.png")
        Image.fromarray(pixels, mode="L").save(written[-1])
    return written


def save_camera(camera: LearnableCamera, out_dir: str | Path, step: int,
                log: CsvLog) -> list[Path]:
    """`write_camera`, and the figure `optics.png` of the camera's values over the steps of
    the run's `train_log.csv` (`log`). Returns the paths written."""
    return [*write_camera(camera, out_dir, step),
            plot_optics(Path(out_dir) / "optics.png", log.rows(), camera)]


def plot_optics(path: str | Path, rows: Sequence[Mapping[str, Any]],
                camera: LearnableCamera) -> Path:
    """The figure `optics.png`: the focus distances, the f-numbers and (learned mask) the
    mask's open share and asymmetry over the training steps of `rows` (`train_log.csv` rows,
    with `log_columns`), and the initial and the current mask.

    Example:
        >>> import tempfile
        >>> cam = LearnableCamera(CameraSettings(0.05, 2.8, [2.0, 6.0], 1.8e-4), (1.0, 10.0))
        >>> rows = [{"step": 1, **log_columns(cam)}, {"step": 2, **log_columns(cam)}]
        >>> plot_optics(Path(tempfile.mkdtemp()) / "optics.png", rows, cam).name
        'optics.png'
    """
    from matplotlib.figure import Figure

    def series(prefix: str) -> dict[str, list[float]]:
        names = [k for k in (rows[0] if rows else {}) if k.startswith(prefix)]
        return {k: [float(r[k]) for r in rows if r.get(k, "") != ""] for k in names}

    steps = [int(r["step"]) for r in rows]
    panels = [("focus distance (m)", series("focus_distance_")),
              ("f-number", series("f_number_"))]
    if camera.mask is not None:
        panels.append(("mask", series("mask_")))
    n = len(panels) + (2 if camera.mask is not None else 0)
    fig = Figure(figsize=(3.2 * n, 3.0), layout="constrained")
    axes = fig.subplots(1, n, squeeze=False)[0]
    for ax, (title, lines) in zip(axes, panels, strict=False):
        for name, values in lines.items():
            ax.plot(steps[:len(values)], values, label=name)
        ax.set_title(title)
        ax.set_xlabel("step")
        if lines:
            ax.legend(fontsize="small")
    if camera.mask is not None:
        for ax, (title, values) in zip(axes[len(panels):], (
                ("initial mask (open disk)", camera.mask.initial),
                (f"mask at step {steps[-1] if steps else 0}", camera.mask.values().detach())),
                strict=True):
            ax.imshow(values.cpu().double().numpy(), cmap="gray", vmin=0, vmax=1)
            ax.set_title(title)
            ax.set_axis_off()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    return path


__all__ = ["CONTRAST_FACTOR", "MASK_KEY", "OPTICS_KEY", "build_learned_camera",
           "checkpoint_aperture", "checkpoint_entries", "depth_contrast", "log_columns",
           "optics_gradients", "param_groups", "plot_optics", "render_batch", "rendered_samples",
           "restore", "save_camera", "starting_camera", "write_camera"]
