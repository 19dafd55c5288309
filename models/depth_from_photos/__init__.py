"""Depth from photos: the label-free methods behind `defocus predict`, one module per concept.

`estimate_depth(focused, settings, depth_range, image=..., method="auto")` is the entry point:
it picks a method by what the photos are and runs it at a working resolution. The modules:

| module | concept |
|---|---|
| `estimate` | `estimate_depth`, the methods by name |
| `thin_lens` | the cost machinery every method shares: candidate depths, each shot's blur, cost aggregation and selection |
| `photometry` | exposure matching between shots, the photos' noise |
| `confidence` | texture to read, depth edges |
| `fourier_blur` | many blurs of one photo through one Fourier transform |
| `sweep` | the sweep over depth with an all-in-focus photo (`SweepDepth`) |
| `semi_global`, `smoothing` | semi-global cost aggregation; edge-aware smoothing of the depth |
| `resolution`, `tiling` | the working resolution; large photos in tiles |
| `trained_network` | a `defocus train` network as a method |
| `blur_net` | the experimental camera-general network that reads blur (`DepthFromDefocus`) |
"""

from .blur_net import BlurNet, DepthFromDefocus, solve_depth, train_blur_net
from .confidence import depth_edge_confidence, texture_confidence, texture_weight
from .estimate import METHODS, choose_method, estimate_depth
from .photometry import match_exposure, noise_model
from .resolution import run_at_working_resolution, scene_range, working_scale
from .sweep import SweepDepth, blur_errors, sweep_cost
from .thin_lens import aggregate_cost, candidate_inverse_depths, select_depth, thin_lens_blur
from .trained_network import TrainedNetwork

__all__ = [
    "METHODS",
    "BlurNet",
    "DepthFromDefocus",
    "SweepDepth",
    "TrainedNetwork",
    "aggregate_cost",
    "blur_errors",
    "candidate_inverse_depths",
    "choose_method",
    "depth_edge_confidence",
    "estimate_depth",
    "match_exposure",
    "noise_model",
    "run_at_working_resolution",
    "scene_range",
    "select_depth",
    "solve_depth",
    "sweep_cost",
    "texture_confidence",
    "texture_weight",
    "thin_lens_blur",
    "train_blur_net",
    "working_scale",
]
