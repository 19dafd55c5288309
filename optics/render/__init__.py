"""Per-pixel PSF rendering: `render_defocus` and its module form `DefocusRenderer`.

| module | job |
|---|---|
| `renderer` | the public API: `render_defocus`, `DefocusRenderer`, the layered mode's helpers |
| `ops` | the Gaussian and clamped-distance filters as `torch.library` custom operators |
| `layer_ops` | the fused layered mode as custom operators (compiled CPU kernels) |
| `profile` | apertures without a kernel (`Mask`, any `Aperture.profile`) in PyTorch |
| `taps` | the window's offsets and distance tables, shared by the above |
| `cpp` | the optional compiled C++ kernels (`csrc/render_kernels.cpp`), built on first use |
| `triton_kernels` | the Triton kernels of the scatter operators on CUDA |
| `backends` | which kernels run the operators where; registers the Triton kernels |
"""

from .renderer import (
    MODES,
    PAPER_COC_RANGE,
    PAPER_HALF_WIDTH,
    PRESETS,
    DefocusRenderer,
    composite_layers,
    layer_weights,
    render_defocus,
    split_layers,
)

__all__ = [
    "MODES",
    "PAPER_COC_RANGE",
    "PAPER_HALF_WIDTH",
    "PRESETS",
    "DefocusRenderer",
    "composite_layers",
    "layer_weights",
    "render_defocus",
    "split_layers",
]
