"""Why depth from real aperture pairs is hard: each cause measured on the DSLR set (DFD-indoor).

For the release's scenes in time order (the last ``--val`` are the validation set; the camera is
fitted on the others), this measures what differs between a real f/8 / f/2.8 pair and the
renderer's model of it, and how much the label-free `estimate_depth` gains on the validation
scenes when each cause is taken into account:

| cause | measured by |
|---|---|
| misalignment of the two photos | `optics.estimate_motion` of the f/2.8 photo against the f/8 one |
| focus breathing | the zoom of that motion |
| exposure, white balance, vignetting | the ratio of the photos' means per channel, centre and corners |
| the f/8 photo is not sharp | its own blur taken as one more shot (relative blur) or ignored |
| focus distance, effective pitch | `optics.calibrate_from_depth` on the training scenes |
| JPEG, demosaicing, a softer lens wide open | the fitted floor: blur in focus |
| PSF shape | the residual of the disk and of the Gaussian at their best blur per depth bin |
| near or far of the focus plane | an oracle that picks the side from the true depth |
| cues to that side in the photos | `optics.side_cues`: the red minus blue blur, and the disk's fit over the Gaussian's, in front of the plane against behind it at the same blur |

and whether the self-supervised loss (`DefocusLoss`, the fitted camera, relative pairs) is right:
scene by scene, its value at the true depth, at its mirror across the focus plane, at the ends
of the depth range, at the focus plane and at the best constant of the training depths
(`models.diagnostics.loss_at_depths`), with the pairs as loaded and registered
(`datasets.pairs.register_focused`), and registered with the fitted blur scaled to the one the
loss prefers on the training scenes (`models.diagnostics.match_blur_scale`). Where the true
depth does not score best, no network trained through the loss can find it.

CPU, about 20 minutes on 2 cores (19 measured, 2026-11-27)::

    python examples/dslr_causes.py --root data/dfd_indoor
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import torch

from datasets import DSLR
from datasets.calibration import calibrate_dataset, depth_pairs
from datasets.pairs import soften
from models.depth_from_photos import estimate_depth
from models.diagnostics import loss_at_depths, true_depth_wins, write_blur_matched_camera
from models.losses import DefocusLoss
from models.metrics import best_constant_depth, depth_metrics
from optics import side_cues
from optics.progress import progress_bar

DEPTH_RANGE = (0.5, 10.0)


def abs_rel(depth: torch.Tensor, sample: dict) -> float:
    return depth_metrics(pred=depth, target=sample["depth"], mask=sample["mask"])["abs_rel"]


def run_variants(val: DSLR, stated: DSLR, floor_px: float, focus_m: float,
                 max_pixels: int) -> dict[str, float]:
    """Mean abs rel of each way to run `estimate_depth` over the validation scenes."""
    totals: dict[str, float] = {}

    def add(name: str, value: float) -> None:
        totals[name] = totals.get(name, 0.0) + value / len(val)

    for index in progress_bar(range(len(val)), desc="validation scenes"):
        fitted, plain = val[index], stated[index]

        def depth(sample: dict, shot: bool, image=None, range_=DEPTH_RANGE, **kw) -> torch.Tensor:
            settings = sample["camera"]
            reference = stated.reference_settings(settings)
            with torch.no_grad():
                return estimate_depth(sample["focused"], settings, range_,
                                      image=sample["image"] if image is None else image,
                                      image_settings=reference if shot else None,
                                      all_in_focus=False, max_pixels=max_pixels, **kw)["depth"]

        add("stated camera, f/8 as all-in-focus, not aligned",
            abs_rel(depth(plain, False, align=False), plain))
        add("stated camera, f/8 as all-in-focus", abs_rel(depth(plain, False), plain))
        add("stated camera, f/8 as a shot", abs_rel(depth(plain, True), plain))
        add("fitted camera, f/8 as a shot", abs_rel(depth(fitted, True), fitted))
        softened = soften(fitted["image"], fitted["camera"], floor_px)
        add("fitted camera, f/8 as a shot, floor", abs_rel(depth(fitted, True, softened), fitted))
        near = depth(fitted, True, softened, (DEPTH_RANGE[0], 0.98 * focus_m),
                     refine_range=False)
        far = depth(fitted, True, softened, (1.02 * focus_m, DEPTH_RANGE[1]), refine_range=False)
        add("... and the depth range beyond the focus plane only", abs_rel(far, fitted))
        truth = fitted["depth"]
        oracle = torch.where((near - truth).abs() < (far - truth).abs(), near, far)
        add("... and the side of the focus plane from the true depth (oracle)",
            abs_rel(oracle, fitted))
        constant = best_constant_depth(target=truth, mask=fitted["mask"])
        add("the best constant of each scene (oracle)",
            abs_rel(torch.full_like(truth, constant), fitted))
    return totals


def photo_differences(train: DSLR, indices: list[int]) -> dict[str, str]:
    """Motion, zoom, exposure and vignetting of the f/2.8 photos against the f/8 ones."""
    from optics import estimate_motion

    motions, centre, corner = [], [], []
    for index in indices:
        sample = train[index]
        image, focused = sample["image"][None].double(), sample["focused"][:1].double()
        motions.append(estimate_motion(image, focused)[0])
        h, w = image.shape[-2:]
        ratio = (focused[0] + 1e-3) / (image[0] + 1e-3)
        centre.append(float(ratio[:, h // 3:2 * h // 3, w // 3:2 * w // 3].median()))
        corner.append(float(torch.cat([ratio[:, :h // 5, :w // 5].reshape(-1),
                                       ratio[:, -h // 5:, -w // 5:].reshape(-1)]).median()))
    motion = torch.stack(motions)
    shift = motion[:, :2].norm(dim=1)
    half_diagonal = math.hypot(*train[0]["image"].shape[-2:]) / 2
    breathing = (motion[:, 2] - 1).abs() * half_diagonal
    q = torch.tensor([0.1, 0.5, 0.9], dtype=torch.float64)
    return {
        "shift (px) p10/median/p90": "/".join(f"{v:.2f}" for v in shift.quantile(q).tolist()),
        "zoom at the corners (px) p10/median/p90":
            "/".join(f"{v:.2f}" for v in breathing.quantile(q).tolist()),
        "exposure ratio f/2.8 / f/8, centre (median)": f"{torch.tensor(centre).median():.3f}",
        "exposure ratio, corners / centre (vignetting)":
            f"{torch.tensor(corner).median() / torch.tensor(centre).median():.3f}",
    }


def print_side_cues(pairs: list, focus_m: float) -> None:
    """Print whether the photos tell near from far of the focus plane (`optics.side_cues` on
    the aligned `pairs` of every training scene): per depth bin, then in front against behind
    at the same blur."""
    cues = side_cues(pairs, focus_m, progress=True)
    print(f"\ncues to the side of the focus plane ({focus_m:.2f} m), {len(pairs)} training scenes "
          "(mean over the scenes that measure the bin, standard error in brackets):")
    print(f"  {'depth m':>8} {'side':>6} {'scenes':>6} {'R px':>6} {'G px':>6} {'B px':>6} "
          f"{'R - B px':>16} {'log disk/Gaussian':>18}")
    for row in cues.by_bin():
        side = "front" if row["side"] < 0 else "behind"
        print(f"  {row['depth_m']:8.2f} {side:>6} {row['pairs']:6.0f} "
              + " ".join(f"{row[f'channel {c} px']:6.2f}" for c in range(3))
              + f" {row['colour spread px']:+8.3f} ({row['colour spread px se']:.3f})"
              f" {row['shape log ratio']:+9.4f} ({row['shape log ratio se']:.4f})")
    for name, c in cues.contrast().items():
        if c["pairs"] == 0:
            print(f"  front minus behind at the same blur, {name}: no scene measures both sides")
            continue
        print(f"  front minus behind at the same blur, {name}: {c['mean']:+.4f} "
              f"(standard error {c['standard_error']:.4f}, z {c['z']:+.1f}, {c['pairs']:.0f} "
              "scenes with both sides)")


def loss_diagnostic(root: Path, scenes: range, cameras: dict[str, Path], constant: float) -> None:
    """Print the loss at the true depth and the alternatives, each scene: the pairs as loaded
    and registered with the fitted camera, then registered with each other camera of
    `cameras` (label -> camera JSON; the first is the fitted one)."""
    fitted = next(iter(cameras.values()))
    variants = [("as loaded", fitted, False), ("registered", fitted, True)]
    variants += [(f"registered, {label}", path, True) for label, path in list(cameras.items())[1:]]
    for label, camera, register in variants:
        pairs = DSLR(root, scenes=scenes, camera=camera, relative=True, register=register)
        rows = loss_at_depths(pairs, DefocusLoss(), DEPTH_RANGE, constants=(constant,))
        wins = sum(true_depth_wins(row) for row in rows)
        names = [k for k in rows[0] if k != "id"]
        print(f"\nthe loss on the {len(rows)} validation scenes, pairs {label}: the true depth "
              f"within 2 % of the best constant on {wins} of {len(rows)}")
        print("  " + " ".join(f"{n:>14}" for n in names))
        for row in rows:
            mark = "" if true_depth_wins(row) else "  <- a constant wins"
            print("  " + " ".join(f"{row[n]:14.4f}" for n in names) + f"  {row['id']}{mark}")


def loss_matched_camera(root: Path, scenes: list[int], camera: Path, out: Path) -> Path:
    """The fitted camera with its blur scaled to what the loss prefers at the true depth of the
    training `scenes` (`write_blur_matched_camera`), written to `out`."""
    pairs = DSLR(root, scenes=scenes, camera=camera, relative=True)
    scale = write_blur_matched_camera(pairs, camera, out, DefocusLoss())
    print(f"the loss prefers {scale:g}x the fitted blur at the true depth of the training "
          f"scenes -> {out}")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, required=True, help="the release's dfd_indoor folder")
    parser.add_argument("--val", type=int, default=20, help="the last this many scenes validate")
    parser.add_argument("--calibrate-every", type=int, default=3,
                        help="fit the camera on every this many training scenes")
    parser.add_argument("--max-pixels", type=int, default=300_000,
                        help="working pixels of estimate_depth")
    parser.add_argument("--out", type=Path, default=Path("runs/dslr_causes"),
                        help="where the fitted camera JSON goes")
    args = parser.parse_args(argv)
    count = len(DSLR(args.root).files)
    if not 0 < args.val < count:
        raise SystemExit(f"--val must leave training scenes: 0 < --val < {count}, got {args.val}")
    train = DSLR(args.root, scenes=range(0, count - args.val))
    every = list(range(0, len(train), args.calibrate_every))
    pairs = depth_pairs(train, progress=True)  # aligned once, for both fits and the side cues
    fits = {psf: calibrate_dataset(train, every, aperture=psf, progress=True,
                                   pairs=[pairs[i] for i in every])
            for psf in ("gaussian:0.5", "disk")}
    fit = fits["gaussian:0.5"]
    args.out.mkdir(parents=True, exist_ok=True)
    fit.to_json(args.out / "camera.json")
    residual = {psf: float((f.curve.errors.min(1).values * f.curve.pixels).sum())
                for psf, f in fits.items()}
    print("photo differences (training scenes):")
    for name, value in photo_differences(train, every).items():
        print(f"  {name}: {value}")
    print(f"camera fitted on {len(every)} training scenes: focus {fit.fit.focus_distance:.2f} m "
          f"(stated 1.7), pitch {float(fit.settings.pixel_pitch[0]) * 1e6:.1f} um for sigma = "
          f"CoC / 2 (stated 55.7 um uncropped), floor {fit.floor_px:.2f} px, curve rmse "
          f"{fit.fit.rmse_px:.2f} px")
    print(f"PSF shape: residual of the disk / the Gaussian at their best blur per depth bin: "
          f"{residual['disk'] / residual['gaussian:0.5']:.4f}")
    near = [float((s["depth"][s["mask"]] < fit.fit.focus_distance).float().mean())
            for s in (train[i] for i in every)]
    print(f"pixels nearer than the focus plane: {100 * sum(near) / len(near):.0f} % (training)")
    print_side_cues(pairs, fit.fit.focus_distance)
    from models.experiment import constant_from_training

    matched = loss_matched_camera(args.root, every, args.out / "camera.json",
                                  args.out / "camera_loss.json")
    loss_diagnostic(args.root, range(count - args.val, count),
                    {"fitted camera": args.out / "camera.json",
                     "the blur the loss prefers": matched}, constant_from_training(train))
    val = DSLR(args.root, scenes=range(count - args.val, count), camera=args.out / "camera.json")
    stated = DSLR(args.root, scenes=range(count - args.val, count))
    print(f"\nestimate_depth on the {len(val)} validation scenes, mean abs rel, depth range "
          f"{DEPTH_RANGE} m:")
    for name, value in run_variants(val, stated, fit.floor_px, fit.fit.focus_distance,
                                    args.max_pixels).items():
        print(f"  {value:.3f}  {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
