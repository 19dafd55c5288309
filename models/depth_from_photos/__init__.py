"""Depth from photos: the label-free methods behind `defocus predict`, one module per concept.

`estimate_depth(focused, settings, depth_range, image=..., method="auto")` is the entry point:
it picks a method by what the photos are and runs it at a working resolution. The modules:

| module | concept |
|---|---|
| `estimate` | `estimate_depth`, the methods by name |
| `thin_lens` | the cost machinery every method shares: candidate depths, each shot's blur, cost aggregation and selection |
| `side` | a stated side of one focus plane: a depth's mirror image, the fold to the stated side, the blurs that contradict it |
| `photometry` | exposure matching between shots, the photos' noise |
| `confidence` | texture to read, depth edges |
| `fourier_blur` | many blurs of one photo through one Fourier transform |
| `cost_volume` | from a cost volume over candidate depths to a depth map (`CostVolumeDepth`) |
| `sweep` | the sweep over depth with an all-in-focus photo (`SweepDepth`) |
| `relative_blur` | depth from two or more focused shots alone, by their relative blur (`RelativeBlurDepth`) |
| `depth_from_focus` | depth from focus for focal stacks (`DepthFromFocus`) |
| `all_in_focus` | the all-in-focus image fused from the shots by their blur |
| `semi_global`, `smoothing` | semi-global cost aggregation; edge-aware smoothing of the depth |
| `resolution`, `tiling` | the working resolution; large photos in tiles |
| `rules` | one refusal for a table of argument rules (the methods' doors) |
| `trained_network` | a `defocus train` network as a method |
| `blur_net` | the experimental camera-general network that reads blur (`DepthFromDefocus`) |
"""

from .all_in_focus import fuse_all_in_focus
from .blur_net import BlurNet, DepthFromDefocus, solve_depth
from .confidence import depth_edge_confidence, texture_confidence, texture_weight
from .cost_volume import CostVolumeDepth
from .depth_from_focus import DepthFromFocus, focus_measures, focus_peak
from .estimate import (
    METHODS,
    ambiguous_depths,
    check_shots_differ,
    choose_method,
    depth_range_problem,
    estimate_depth,
    join_shots,
)
from .photometry import match_exposure, noise_model
from .relative_blur import RelativeBlurDepth, relative_blur_cost, relative_blur_px
from .resolution import scene_range, widen_cut_range, working_scale
from .sweep import SweepDepth, blur_errors, sweep_channels, sweep_cost
from .thin_lens import (
    aggregate_cost,
    candidate_inverse_depths,
    mirrored_depths,
    select_depth,
    thin_lens_blur,
)
from .trained_network import TrainedNetwork

__all__ = [
    "METHODS",
    "BlurNet",
    "CostVolumeDepth",
    "DepthFromDefocus",
    "DepthFromFocus",
    "RelativeBlurDepth",
    "SweepDepth",
    "TrainedNetwork",
    "aggregate_cost",
    "ambiguous_depths",
    "blur_errors",
    "candidate_inverse_depths",
    "check_shots_differ",
    "choose_method",
    "depth_edge_confidence",
    "depth_range_problem",
    "estimate_depth",
    "focus_measures",
    "focus_peak",
    "fuse_all_in_focus",
    "join_shots",
    "match_exposure",
    "mirrored_depths",
    "noise_model",
    "relative_blur_cost",
    "relative_blur_px",
    "scene_range",
    "select_depth",
    "solve_depth",
    "sweep_channels",
    "sweep_cost",
    "texture_confidence",
    "texture_weight",
    "thin_lens_blur",
    "widen_cut_range",
    "working_scale",
]
