"""Helpers shared by the training tests."""

from models.training import TrainConfig


def tiny_config(out_dir, **changes) -> TrainConfig:
    """A `TrainConfig` that trains a width-4 network for 4 steps (changes override)."""
    base = dict(steps=4, batch_size=2, lr=1e-3, width=4, out_dir=out_dir, depth_min=1.5,
                depth_max=6.0, progress=False, seed=0)
    base.update(changes)
    return TrainConfig(**base)
