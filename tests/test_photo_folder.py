"""`datasets.PhotoFolder`: a folder of the user's own scenes trains a network without code
(`defocus train --data folder`)."""

from __future__ import annotations

import json
import shutil

import pytest
import torch

from datasets import PhotoFolder
from datasets.io import DataFormatError
from defocus.app.sample import SAMPLE_FOCUS, write_sample_set
from defocus.cli import main


@pytest.fixture(scope="module")
def sample_scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sample") / "scene"
    write_sample_set(folder, scale=0.12)
    return folder


def test_a_sample_set_is_a_scene_of_a_photo_folder(sample_scene):
    data = PhotoFolder(sample_scene.parent)
    sample = data[0]
    assert data.ids == ["scene"] and sample["focused"].shape[0] == 2  # camera.json: near, far
    assert sample["image"].shape == sample["focused"].shape[1:]
    focus = sample["camera"].focus_distance.tolist()
    assert focus == pytest.approx([SAMPLE_FOCUS["near"], SAMPLE_FOCUS["far"]])
    assert not bool(sample["mask"].any())  # no ground truth
    near = sample["focused"][0]
    from datasets.photos import read_photo

    assert torch.allclose(near, read_photo(sample_scene / "near.png")[0])


def test_train_on_a_folder_of_own_photos(sample_scene, tmp_path, capsys):
    root = tmp_path / "mine"
    shutil.copytree(sample_scene, root / "scene_a")
    shutil.copytree(sample_scene, root / "scene_b")
    for scene in ("scene_a", "scene_b"):  # one camera for all: the three-shot stack
        (root / scene / "camera.json").unlink()
    shutil.copy(sample_scene / "camera_stack.json", root / "camera.json")
    out = tmp_path / "run"
    assert main(["train", "--data", "folder", "--root", str(root), "--set", "steps=2",
                 "batch_size=2", "width=4", "--out", str(out), "--quiet"]) == 0
    assert "trained 2 steps" in capsys.readouterr().out
    import yaml

    config = yaml.safe_load((out / "config.yaml").read_text())
    assert config["n_focus"] == 3  # from the data: the stack has three shots


def test_a_scene_without_its_photo_list_is_refused_by_name(sample_scene, tmp_path):
    root = tmp_path / "bad"
    shutil.copytree(sample_scene, root / "scene")
    data = json.loads((root / "scene" / "camera.json").read_text())
    del data["photos"]
    (root / "scene" / "camera.json").write_text(json.dumps(data))
    with pytest.raises(DataFormatError, match=r"camera.json: \"photos\" must list"):
        PhotoFolder(root)
    (root / "scene" / "far.png").unlink()
    data["photos"] = ["near.png", "far.png"]
    (root / "scene" / "camera.json").write_text(json.dumps(data))
    with pytest.raises(FileNotFoundError, match=r"names \['far.png'\]"):
        PhotoFolder(root)


def test_hidden_and_tool_folders_are_not_scenes(sample_scene, tmp_path):
    """`.ipynb_checkpoints` or `__MACOSX` beside the scenes blocked loading ("no camera.json")."""
    import shutil

    root = tmp_path / "mine"
    shutil.copytree(sample_scene, root / "scene")
    for name in (".ipynb_checkpoints", "__MACOSX"):
        (root / name).mkdir()
    assert PhotoFolder(root).ids == ["scene"]
