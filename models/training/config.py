"""The configuration of a training run: `TrainConfig` (every field checked when it is built,
YAML in and out, `key=value` overrides). `models.training.Trainer` runs it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from torch import nn

from optics import DEFAULT_APERTURE, LEARNABLE, aperture_spec
from optics.render import MODES as RENDER_MODES

from ..depth_head import DEPTH_SPACINGS, SIDES
from ..devices import check_device
from ..losses import HINT_GATES
from ..networks import INPUT_MODES, NETWORKS, build_network

#: values of `TrainConfig.supervision`: through the renderer (no depth labels) or on depth
SUPERVISIONS = ("self", "depth")
#: values of `TrainConfig.resume` (see its field comment)
RESUME_MODES = ("auto", "resume", "overwrite")
#: config keys that may differ between a run and its continuation (they do not change the
#: numbers: where it runs, what it shows and how often it saves)
RUN_CONTROL_KEYS = ("out_dir", "resume", "device", "progress", "checkpoint_every",
                    "checkpoint_minutes", "keep_checkpoints", "workers", "compile",
                    "compile_mode", "minutes")
#: values of `TrainConfig.optics_objective` (see its field comment)
OPTICS_OBJECTIVES = ("loss", "contrast")
#: values of `TrainConfig.precision`
PRECISIONS = ("auto", "float32", "bfloat16")
#: values of `TrainConfig.compile_mode` (`torch.compile`'s modes)
COMPILE_MODES = ("default", "reduce-overhead", "max-autotune", "max-autotune-no-cudagraphs")
#: the largest `TrainConfig.seed` (the batch order seeds a 64-bit generator with a multiple of it)
MAX_SEED = 2**32 - 1


def _finite(low: float, strict: bool = False):
    """A field rule: a finite number above `low` (or equal unless `strict`)."""
    return lambda v: math.isfinite(v) and (v > low if strict else v >= low)


#: the allowed values of the `TrainConfig` fields that name a choice
_CHOICES = {"network": tuple(NETWORKS), "input_mode": INPUT_MODES,
            "depth_spacing": DEPTH_SPACINGS, "side": SIDES, "supervision": SUPERVISIONS,
            "lr_schedule": ("cosine", "constant"), "render_mode": RENDER_MODES,
            "resume": RESUME_MODES, "precision": PRECISIONS, "compile_mode": COMPILE_MODES,
            "hint_gate": HINT_GATES, "optics_objective": OPTICS_OBJECTIVES}
#: (fields, rule, what the rule asks) of the numeric `TrainConfig` fields
_RULES = (
    (("steps", "batch_size", "width", "log_every"), lambda v: v >= 1, "an integer >= 1"),
    (("mask_size", "scales"), lambda v: v >= 2, "an integer >= 2"),
    (("sweep_inputs",), lambda v: v == 0 or v >= 2, "0 (none) or an integer >= 2"),
    (("n_focus", "checkpoint_every", "keep_checkpoints", "val_every", "figure_every"),
     lambda v: v >= 0, "an integer >= 0"),
    (("workers",), lambda v: v >= -1, "an integer >= -1"),
    (("seed",), lambda v: 0 <= v <= MAX_SEED, f"an integer in [0, {MAX_SEED}] (2**32 - 1)"),
    (("ssim_window", "max_kernel_size"), lambda v: v >= 1 and v % 2 == 1,
     "a positive odd number of pixels"),
    (("lr", "depth_min", "depth_max", "f_number_min", "f_number_max"),
     _finite(0, strict=True), "a finite number > 0"),
    (("weight_decay", "grad_clip", "sharpness_weight", "smoothness_weight", "optics_lr",
      "checkpoint_minutes", "minutes", "mask_start_noise", "hint_weight", "read_noise",
      "shot_noise"), _finite(0),
     "a finite number >= 0 (0: off)"),
    (("ssim_weight",), lambda v: 0 <= v <= 1, "in [0, 1]"),
    (("focus_distance",), _finite(0), "a finite number of metres >= 0 (0: none)"),
)


@dataclass
class TrainConfig:
    """Everything a training run depends on (lengths in metres).

    Build from a YAML file and `key=value` overrides with `load` (also `from_yaml`,
    `override`: `["steps=100", "lr=3e-4"]`), save with `to_yaml`.

    Example:
        >>> cfg = TrainConfig(steps=10).override(["lr=3e-4", "input_mode=aif"])
        >>> cfg.steps, cfg.lr, cfg.input_mode
        (10, 0.0003, 'aif')
    """

    #: optimisation steps
    steps: int = 300
    #: samples per step and per process
    batch_size: int = 8
    #: Adam learning rate (the paper: 2e-5 for its large network)
    lr: float = 1e-3
    #: "small" (CPU encoder-decoder) or "paper" (ResNet-50 + dense ASPP + attention + DeepLabV3+)
    network: str = "small"
    #: "aif+focused" (depth from defocus at test time) or "aif" (monocular at test time)
    input_mode: str = "aif+focused"
    #: "self" (rendered vs real focused images, no depth labels) or "depth" (supervised baseline)
    supervision: str = "self"
    #: output folder (logs, checkpoints, figures)
    out_dir: Path = Path("runs/train")
    #: random seed (weights, batch order), 0 to 2**32 - 1
    seed: int = 0
    #: nearest depth the network can output, metres
    depth_min: float = 1.0
    #: farthest depth the network can output, metres
    depth_max: float = 10.0
    #: "depth" or "inverse": the network's output spaced evenly in depth or in inverse depth
    depth_spacing: str = "depth"
    #: "both", "beyond" or "before": the side of the focus plane the network's output may put
    #: a blur that both sides explain (`models.depth_head.DepthHead`; not "both" needs
    #: focus_distance); a prior the user states, for one focus setting
    side: str = "both"
    #: focus distance, metres, of the side prior (0: none; needed unless side is "both")
    focus_distance: float = 0.0
    #: focused images per sample (0: as many as the first training sample holds)
    n_focus: int = 0
    #: first-scale channels of the small network
    width: int = 32
    #: resolutions of the small network's encoder (`models.networks.SmallDepthNet`): 3 see about
    #: 40 pixels around each pixel, 5 about 160 (scene layout for input_mode "aif")
    scales: int = 3
    #: the small network also sees each pixel's row in its input (`SmallDepthNet`): where in a
    #: photo things tend to be near. Train it on whole images (crop 0): a crop's rows are not
    #: the photo's
    position: bool = False
    #: the network also reads the cost of this many candidate depths between depth_min and
    #: depth_max and refines the cheapest one's depth (`models.networks.SmallDepthNet`'s
    #: `sweep`; "aif+focused" and side "both" only; 0: none): the all-in-focus image blurred at
    #: each candidate's blur against the focused images, through the learned mask where one is
    #: learned, signed for a coded aperture
    sweep_inputs: int = 0
    #: AdamW weight decay
    weight_decay: float = 0.0
    #: "cosine" (decay to 0 over steps) or "constant"
    lr_schedule: str = "cosine"
    #: gradient-norm clipping (0: off)
    grad_clip: float = 1.0
    #: SSIM share of the photometric loss
    ssim_weight: float = 0.85
    #: weight of the sharpness-map L1 term
    sharpness_weight: float = 0.1
    #: weight of the edge-aware depth smoothness
    smoothness_weight: float = 0.001
    #: weight of the depth hints (0: off; `models.losses.DefocusLoss`, after Watson et al.):
    #: self-supervised runs only, on samples that carry a `hint` (a depth found without labels,
    #: `DepthDataset.with_hints`; `models.training.hints.label_free_hints` finds them)
    hint_weight: float = 0.0
    #: where the hints pull: "photometric" (where a hint renders the focused images better
    #: than the network's depth) or "always" (every pixel: for real photos that the renderer
    #: explains imperfectly, where a wrong depth can render them better than the true one)
    hint_gate: str = "photometric"
    #: SSIM window width, pixels
    ssim_window: int = 7
    #: PSF used to render in the loss, a spec of optics.aperture_spec: "gaussian" (sigma = CoC/2),
    #: "gaussian:S", "disk", "polygon:N"; kept in its canonical form ("gaussian" is "gaussian:0.5")
    aperture: str = DEFAULT_APERTURE
    #: renderer semantics: "scatter", "gather" or "layered"
    render_mode: str = "scatter"
    #: largest PSF window, pixels
    max_kernel_size: int = 63
    #: random horizontal flips of the training samples
    flip: bool = True
    #: write a train_log.csv row every this many steps (>= 1)
    log_every: int = 1
    #: save a checkpoint every this many steps (0: off; see checkpoint_minutes). Checkpoints are
    #: also written at the end, on SIGINT/SIGTERM (then the run stops) and when a step fails
    checkpoint_every: int = 0
    #: save a checkpoint when this many minutes passed since the last one (0: off)
    checkpoint_minutes: float = 10.0
    #: keep only the newest this many step_XXXXXX.pt checkpoints (0: keep all; last.pt is kept)
    keep_checkpoints: int = 3
    #: evaluate on the validation set every this many steps (0: only at the end)
    val_every: int = 0
    #: write a figure every this many steps (0: only at the end)
    figure_every: int = 0
    #: what to do when out_dir already holds a run: "auto" (continue it when its config is the
    #: same, else refuse and name the keys that differ), "resume" (continue it, also with a larger
    #: steps; refused when anything else differs or there is no run; `defocus train --resume`) or
    #: "overwrite" (delete its config, logs, checkpoints and figures, then start at step 0;
    #: `--overwrite`). true means "auto", false "overwrite". device, progress, out_dir and the
    #: checkpoint settings may always differ
    resume: str = "auto"
    #: "auto" (CUDA when available), "cpu", "cuda", ... (refused when this machine lacks it)
    device: str = "auto"
    #: processes that prepare batches ahead of the step (0: the training loop prepares each
    #: batch itself; -1: automatic, `models.training.batches.auto_workers`); the batches are
    #: the same either way
    workers: int = -1
    #: the network's arithmetic: "float32", "bfloat16" (autocast around the network; the
    #: small network's output layer, the renderer, its PSF weights and the loss stay float32), or "auto":
    #: bfloat16 on a CPU with native bfloat16 arithmetic (AVX-512 BF16, AMX; there it about
    #: halves the network's time), float32 elsewhere (`models.training.forward.network_precision`)
    precision: str = "float32"
    #: run the network and the loss through `torch.compile`, fused into one graph (the first
    #: step compiles for a minute or two; later ones are faster on a GPU)
    compile: bool = False
    #: `torch.compile`'s mode when `compile`: "default", "reduce-overhead" (CUDA graphs as
    #: well: on a GPU the host launches a step's kernels in one call), "max-autotune", ...
    compile_mode: str = "default"
    #: what the camera learns jointly with the network (`optics.LearnableCamera`): "" (nothing,
    #: the data's fixed camera) or any of "focus", "f-number", "mask" joined by commas (a list
    #: is read too). The focused images of each batch are then rendered from its all-in-focus
    #: image and depth through the learned camera: data whose focused images are synthesised
    #: only (procedural scenes, synthesised focus), with depth at every pixel
    learn_optics: str = ""
    #: Adam learning rate of the learned optics (their free parameters, logits); 0 renders
    #: every batch through the starting camera, unlearned: the fixed camera under the same
    #: noise, the baseline a learned camera is compared with
    optics_lr: float = 0.01
    #: what a self-supervised run's learned camera lowers: "contrast" (the training loss
    #: relative to the loss at depths 25 % nearer and farther than the network's: photos that
    #: tell the network's depth from its neighbours;
    #: `models.training.learned_camera.depth_contrast`) or "loss" (the training loss itself,
    #: as the network does, which less blur at any depth lowers too: the camera stops down or
    #: focuses onto the scenes' depths). Runs on depth labels learn the camera from the labels'
    #: loss either way
    optics_objective: str = "contrast"
    #: read noise (standard deviation, full scale 1) of the focused images rendered through a
    #: learned camera, at the starting camera's exposure (`optics.noise_std`, as
    #: `datasets.capture.CaptureNoise`). A camera that gathers less light (a larger f-number)
    #: has more, as on a real sensor: stopping down is not free
    read_noise: float = 0.004
    #: shot noise of those images, standard deviation `sqrt(shot_noise * intensity)` at the
    #: starting camera's exposure, more where the camera gathers less light
    shot_noise: float = 0.0004
    #: smallest f-number a learned f-number may take (the lens's limit)
    f_number_min: float = 1.0
    #: largest f-number a learned f-number may take (the lens's limit)
    f_number_max: float = 22.0
    #: side of the grid of a learned aperture mask (learn_optics with "mask"), cells
    mask_size: int = 16
    #: seeded noise (standard deviation) on the learned mask's logits at the start, at the open
    #: disk's light: 0 starts at the disk itself. With one focus plane, a point-symmetric mask
    #: blurs a depth and its mirror alike and learning leaves it only slowly; a start without
    #: point symmetry lets the code learn to tell near from far
    mask_start_noise: float = 0.0
    #: time budget of one `fit`, minutes (0: none): training stops after the step that spends
    #: it and saves a checkpoint, as at the end
    minutes: float = 0.0
    #: tqdm progress bar
    progress: bool = True
    #: extra keys for your own code (kept in config.yaml)
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.out_dir = Path(self.out_dir)
        self.learn_optics = _learned_optics(self.learn_optics)
        if isinstance(self.resume, bool):
            self.resume = "auto" if self.resume else "overwrite"
        for item in dataclasses.fields(self):
            _check_type(item.name, getattr(self, item.name), item.type)
            if item.type == "float":
                setattr(self, item.name, float(getattr(self, item.name)))
        refused = [(name, f"one of {allowed}") for name, allowed in _CHOICES.items()
                   if getattr(self, name) not in allowed]
        refused += [(name, phrase) for names, rule, phrase in _RULES for name in names
                    if not rule(getattr(self, name))]
        if refused:
            name, phrase = refused[0]
            raise ValueError(f"{name} must be {phrase}, got {getattr(self, name)!r}")
        try:
            self.aperture = aperture_spec(self.aperture)
        except (TypeError, ValueError) as error:
            raise ValueError(f"aperture {self.aperture!r} is not a PSF spec: {error}") from None
        for refused, message in (
            (not self.depth_min < self.depth_max, "need 0 < depth_min < depth_max metres, got "
             f"{self.depth_min!r} and {self.depth_max!r}"),
            (self.side != "both" and not self.depth_min < self.focus_distance < self.depth_max,
             f"side {self.side!r} needs a focus_distance between depth_min and depth_max, got "
             f"{self.focus_distance!r}"),
            (not self.f_number_min < self.f_number_max, "need f_number_min < f_number_max, "
             f"got {self.f_number_min!r} and {self.f_number_max!r}"),
            (self.hint_weight > 0 and bool(self.learn_optics), f"hint_weight="
             f"{self.hint_weight!r} with learn_optics={self.learn_optics!r}: the hints were "
             "found with the data's camera, not the one being learned; set hint_weight=0"),
            (self.compile and bool(self.learn_optics), f"compile=true with learn_optics="
             f"{self.learn_optics!r} is not supported yet (torch.compile fails on the gradient "
             "that reaches the network's input from the learned camera): set compile=false"),
            (self.sweep_inputs > 0 and self.input_mode != "aif+focused", f"sweep_inputs="
             f"{self.sweep_inputs!r} needs input_mode 'aif+focused' (the sweep compares the "
             f"focused images with the all-in-focus one), got {self.input_mode!r}"),
            (self.compile_mode != "default" and not self.compile,
             f"compile_mode={self.compile_mode!r} needs compile=true (without it nothing is "
             "compiled)")):
            if refused:
                raise ValueError(message)
        check_device(self.device)

    def build_network(self) -> nn.Module:
        """The untrained network of this config (`models.networks.build_network`).

        Example:
            >>> TrainConfig(width=8, scales=4, n_focus=2).build_network().scales
            4
        """
        return build_network(self.network, self.input_mode, self.n_focus, self.depth_min,
                             self.depth_max, self.width, self.depth_spacing, self.side,
                             self.focus_distance or None, self.scales, self.position,
                             self.sweep_inputs)

    def to_dict(self) -> dict[str, Any]:
        data = dataclasses.asdict(self)
        data["out_dir"] = str(self.out_dir)
        return data

    def to_yaml(self, path: str | Path) -> None:
        Path(path).write_text(yaml.safe_dump(self.to_dict(), sort_keys=False))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> TrainConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown config keys {unknown}; allowed: {sorted(known)}")
        return cls(**{k: _coerce(cls, k, v) for k, v in data.items()})

    @classmethod
    def load(cls, path: str | Path | None = None, overrides: Sequence[str] = (),
             **defaults: Any) -> TrainConfig:
        """The one way a config is built from text: `defaults` (fields a program chooses), the
        YAML file `path` on top, then the `key=value` `overrides` (values parsed as YAML).

        Raises:
            ValueError: the file is not UTF-8 YAML text, is not a mapping, names a key twice
                (YAML would keep the last silently); an override is not `key=value`, its value
                is not YAML or a key is given twice (which value was meant is unknown); or the
                result is an invalid config.

        Example:
            >>> TrainConfig.load(None, ["lr=3e-4"], steps=10).lr
            0.0003
        """
        return cls.from_dict({**defaults, **(read_yaml_mapping(path) if path else {}),
                              **parse_overrides(overrides)})

    @classmethod
    def from_yaml(cls, path: str | Path) -> TrainConfig:
        """Load a config from a YAML mapping of field names to values (`load`)."""
        return cls.load(path)

    def override(self, assignments: Sequence[str]) -> TrainConfig:
        """A copy with `key=value` assignments applied (`load`)."""
        return TrainConfig.load(None, assignments, **self.to_dict())


def _learned_optics(value: Any) -> str:
    """`TrainConfig.learn_optics` in its canonical form: the names of `optics.LEARNABLE` it
    holds, in that order, joined by commas ("" for none).

    Example:
        >>> _learned_optics("mask, focus"), _learned_optics(["f-number"]), _learned_optics(None)
        ('focus,mask', 'f-number', '')
    """
    if value is None:
        return ""
    if isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value):
        names = [v.strip() for v in value]
    elif isinstance(value, str):
        names = [v.strip() for v in value.split(",") if v.strip()]
    else:
        names = None
    if names is None or any(name not in LEARNABLE for name in names) \
            or len(set(names)) != len(names):
        raise ValueError(f"learn_optics must name some of {', '.join(LEARNABLE)} (each once, "
                         f"joined by commas; empty: none), got {value!r}")
    return ",".join(name for name in LEARNABLE if name in names)


def read_yaml_mapping(path: str | Path) -> dict[str, Any]:
    """The mapping of config keys that the YAML file `path` holds ({} for an empty file).

    Raises:
        ValueError: the file is not UTF-8 YAML text, not a mapping, or names a key twice.
    """
    try:
        data = parse_yaml(Path(path).read_text(encoding="utf-8"), str(path)) or {}
        refusal = None if isinstance(data, Mapping) else \
            f"{path} must hold a YAML mapping of config keys, got {type(data).__name__}"
    except UnicodeDecodeError as error:
        refusal = f"config {path} is not UTF-8 YAML text (byte {error.start} cannot be read); " \
            "give a YAML file of config keys"
    if refusal is not None:
        raise ValueError(refusal)
    return dict(data)


def parse_overrides(assignments: Sequence[str]) -> dict[str, Any]:
    """The values of `key=value` assignments, parsed as YAML.

    Example:
        >>> parse_overrides(["steps=5", "aperture=disk"])
        {'steps': 5, 'aperture': 'disk'}
    """
    data: dict[str, Any] = {}
    seen: dict[str, str] = {}
    for item in assignments:
        key, sep, value = item.partition("=")
        key = key.strip()
        refused = (f"overrides must look like key=value, got {item!r}" if not sep else
                   f"config key {key} is set twice in the overrides ({seen[key]!r} and "
                   f"{item!r}): give each key once" if key in seen else None)
        if refused:
            raise ValueError(refused)
        seen[key] = item
        data[key] = parse_yaml(value, f"override {item!r}")
    return data


class _UniqueKeyLoader(yaml.SafeLoader):
    """`yaml.SafeLoader` that refuses a mapping naming a key twice."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        keys = [self.construct_object(key, deep=deep) for key, _ in node.value]
        for i, key in enumerate(keys):
            if isinstance(key, str) and key in keys[:i]:
                line = node.value[i][0].start_mark.line + 1
                raise ValueError(f"config key {key} is given twice (again on line {line}): give "
                                 "each key once")
        return super().construct_mapping(node, deep=deep)


def parse_yaml(text: str, where: str) -> Any:
    """The value of YAML `text`, read safely (`yaml.SafeLoader`); a mapping must name each key
    once.

    Raises:
        ValueError: `text` is not YAML (naming `where`, the line and the problem) or a mapping
            names a key twice.

    Example:
        >>> parse_yaml("steps: 3", "config.yaml")
        {'steps': 3}
        >>> parse_yaml("steps: 3\\nsteps: 4", "config.yaml")
        Traceback (most recent call last):
        ...
        ValueError: config.yaml: config key steps is given twice (again on line 2): give each key once
    """
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    except (yaml.YAMLError, ValueError) as error:  # a ValueError: a key given twice
        mark = getattr(error, "problem_mark", None)
        line = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(error, "problem", None) or type(error).__name__
        raise ValueError(f"{where} is not valid YAML{line}: {problem}"
                         if isinstance(error, yaml.YAMLError) else f"{where}: {error}") from None


def _check_type(name: str, value: Any, kind: Any) -> None:
    """Raise `ValueError` unless `value` has the field type `kind` (ints are floats too)."""
    kind = kind if isinstance(kind, str) else getattr(kind, "__name__", "")
    allowed = {"int": (int,), "float": (int, float), "bool": (bool,), "str": (str,),
               "Path": (Path,)}.get(kind)
    if kind.startswith("dict"):
        allowed = (dict,)
    if allowed is None:
        return
    if isinstance(value, bool) and kind in ("int", "float"):
        allowed = ()
    if not isinstance(value, allowed):
        raise ValueError(f"config key {name} must be of type {kind}, got {value!r}")


def _convert(kind: str, value: Any) -> Any:
    """`value` as a field of type `kind`, or `_REFUSED`."""
    if kind in ("int", "float", "bool") and isinstance(value, bool) != (kind == "bool"):
        return _REFUSED
    try:
        if kind == "int":
            return _REFUSED if isinstance(value, float) and not value.is_integer() else int(value)
        converters = {"float": float, "Path": Path, "str": str}
        return converters[kind](value) if kind in converters else value
    except (TypeError, ValueError, OverflowError):
        return _REFUSED


_REFUSED = object()


def _coerce(cls: type, name: str, value: Any) -> Any:
    """Convert a YAML value to the type of field `name`."""
    kind = {f.name: f.type for f in dataclasses.fields(cls)}.get(name)
    kind = kind if isinstance(kind, str) else getattr(kind, "__name__", "")
    if name == "resume" and isinstance(value, bool):
        return value  # true / false: mapped to "auto" / "overwrite"
    if name == "learn_optics" and (value is None or isinstance(value, list)):
        return value  # a YAML list or nothing: read by `_learned_optics`
    if kind == "int" and isinstance(value, str) and not value.strip().lstrip("+-").isdigit():
        try:
            value = float(value)  # "1e3": YAML reads an exponent without a dot as text
        except ValueError:
            pass
    converted = _convert(kind, value)
    if converted is _REFUSED:
        raise ValueError(f"config key {name} must be of type {kind}, got {value!r}")
    return converted
