"""Make the pictures of the rendering tutorial (offline: scikit-image's motorcycle scene).

    .venv/bin/python docs/tutorials/make_rendering_figures.py

writes ``docs/tutorials/img/render_*.png``: a focus and aperture sweep, the three modes on the
real scene, the three modes at a synthetic depth edge, and the aperture shapes.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402
import torch.nn.functional as F  # noqa: E402
from kornia.color import linear_rgb_to_rgb  # noqa: E402

from datasets.middlebury import load_motorcycle  # noqa: E402
from optics import Camera, Disk, Gaussian, Mask, Polygon, Sensor, ThinLens  # noqa: E402

OUT = Path(__file__).resolve().parent / "img"
MODES = ("gather", "scatter", "layered")
FOCAL_LENGTH = 0.085  # metres: a portrait lens


def save(fig, name: str) -> None:
    """Write a PNG with a 256-colour palette (a third of the size, no visible loss here)."""
    from PIL import Image

    path = OUT / name
    fig.savefig(path, dpi=72)
    plt.close(fig)
    Image.open(path).convert("RGB").quantize(256, dither=Image.Dither.NONE).save(path, optimize=True)


def show(ax, image, title=""):
    ax.imshow(linear_rgb_to_rgb(image.clamp(0, 1)).permute(1, 2, 0).numpy())
    ax.set_title(title, fontsize=9)
    ax.axis("off")


def motorcycle(scale: float = 0.5):
    """The scene at ``scale`` and a camera factory whose pixels match its calibration."""
    scene = load_motorcycle()
    image = F.interpolate(scene["image"], scale_factor=scale, mode="area")
    depth = F.interpolate(scene["depth"], scale_factor=scale, mode="nearest")
    pitch = FOCAL_LENGTH / scene["calib"]["focal_length_px"]  # sensor pitch at full resolution

    def camera(focus, f_number, aperture=None):
        return Camera(ThinLens(FOCAL_LENGTH, f_number, focus),
                      Sensor(pitch, downsample=1 / scale), aperture)

    return image, depth, camera


@torch.no_grad()
def focus_sweep_figure(image, depth, camera) -> None:
    focus_distances, f_numbers = (2.3, 3.0, 4.5), (1.4, 4.0)
    fig, axes = plt.subplots(2, 4, figsize=(13, 4.6), constrained_layout=True)
    show(axes[0, 0], image[0], "all in focus")
    im = axes[1, 0].imshow(depth[0, 0].numpy(), cmap="magma_r")
    axes[1, 0].set_title("depth (m)", fontsize=9)
    axes[1, 0].axis("off")
    fig.colorbar(im, ax=axes[1, 0], shrink=0.8)
    for row, f_number in enumerate(f_numbers):
        for col, focus in enumerate(focus_distances, start=1):
            cam = camera(focus, f_number)
            coc = cam.coc_px(depth)
            show(axes[row, col], cam.render(image, depth)[0],
                 f"focus {focus} m, f/{f_number}: CoC up to {float(coc.max()):.1f} px")
    save(fig, "render_focus_sweep.png")


def edge_crop(depth, size=70):
    """A window centred on the strongest depth edge (away from the image border)."""
    d = depth[0, 0]
    grad = (d[1:, 1:] - d[:-1, 1:]).abs() + (d[1:, 1:] - d[1:, :-1]).abs()
    h, w = grad.shape
    inner = torch.zeros_like(grad)
    inner[size:h - size, size:w - size] = grad[size:h - size, size:w - size]
    y, x = divmod(int(inner.argmax()), w)
    return slice(y - size // 2, y + size // 2), slice(x - size // 2, x + size // 2)


@torch.no_grad()
def modes_figure(image, depth, camera) -> None:
    cam = camera(2.3, 1.4)  # the motorbike in focus, the wall behind it blurred
    rows, cols = edge_crop(depth)
    fig, axes = plt.subplots(2, 4, figsize=(13, 5.2), constrained_layout=True)
    show(axes[0, 0], image[0], "all in focus (box: crop below)")
    axes[0, 0].add_patch(plt.Rectangle((cols.start, rows.start), cols.stop - cols.start,
                                       rows.stop - rows.start, fill=False, color="yellow"))
    show(axes[1, 0], image[0, :, rows, cols], "all in focus, crop")
    for i, mode in enumerate(MODES, start=1):
        out = cam.render(image, depth, mode=mode)[0]
        show(axes[0, i], out, f"{mode}")
        show(axes[1, i], out[:, rows, cols], f"{mode}, crop")
    save(fig, "render_modes.png")


@torch.no_grad()
def depth_edge_figure() -> None:
    """Sharp red/white stripes (in focus, near) beside a blurred blue/white pattern (far)."""
    h, w = 48, 96
    xs = torch.arange(w)
    stripes = ((xs // 4) % 2).float().expand(h, w)
    image = torch.stack([torch.ones(h, w), 1 - stripes, 1 - stripes])  # red and white
    far = xs >= w // 2
    image[:, :, far] = torch.stack([1 - stripes, 1 - stripes, torch.ones(h, w)])[:, :, far]
    depth = torch.where(far, 8.0, 2.0).expand(1, 1, h, w).clone()
    cam = Camera(ThinLens(0.05, 1.4, 2.0), Sensor(6e-5))  # far side: CoC about 12 px
    fig, axes = plt.subplots(1, 5, figsize=(15, 2.6), constrained_layout=True,
                             gridspec_kw={"width_ratios": [1, 1, 1, 1, 1.3]})
    show(axes[0], image, "all in focus: near | far")
    row = h // 2
    axes[4].plot(image[2, row].numpy(), color="0.6", label="all in focus")
    for i, mode in enumerate(MODES, start=1):
        out = cam.render(image[None], depth, mode=mode)[0]
        show(axes[i], out, mode)
        axes[4].plot(out[2, row].numpy(), label=mode)
    axes[4].axvline(w // 2 - 0.5, color="k", lw=0.5)
    axes[4].set_title("blue channel along a row (near: left)", fontsize=9)
    axes[4].set_xlabel("x (pixels)")
    axes[4].legend(fontsize=7, loc="lower left")
    save(fig, "render_depth_edge.png")


@torch.no_grad()
def apertures_figure() -> None:
    """Point lights on walls at several depths through each aperture shape (scatter mode)."""
    h, w = 64, 160
    image = torch.full((1, 3, h, w), 0.02)
    depth = torch.full((1, 1, h, w), 2.0)
    for x, z in [(20, 2.0), (55, 2.6), (95, 3.5), (135, 6.0)]:
        image[0, :, h // 2, x] = 60.0
        depth[..., x - 17:] = z  # each point lies on a dark wall at its own depth
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, 31), torch.linspace(-1, 1, 31), indexing="ij")
    ring = ((xx**2 + yy**2).sqrt() - 0.75).abs() < 0.25
    shapes = {"Gaussian()": Gaussian(), "Disk()": Disk(), "Polygon(6)": Polygon(6),
              "Mask(ring)": Mask(ring.float())}
    fig, axes = plt.subplots(1, 4, figsize=(15, 1.9), constrained_layout=True)
    for ax, (name, aperture) in zip(axes, shapes.items(), strict=True):
        cam = Camera(ThinLens(0.05, 1.4, 2.0), Sensor(3e-5), aperture)
        show(ax, cam.render(image, depth)[0], f"{name}: points at 2, 2.6, 3.5, 6 m")
    save(fig, "render_apertures.png")


def main() -> None:
    OUT.mkdir(exist_ok=True)
    image, depth, camera = motorcycle()
    focus_sweep_figure(image, depth, camera)
    modes_figure(image, depth, camera)
    depth_edge_figure()
    apertures_figure()
    for path in sorted(OUT.glob("render_*.png")):
        print(f"{path} ({path.stat().st_size // 1024} KB)")


if __name__ == "__main__":
    main()
