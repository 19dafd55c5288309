"""The two-focus network exports to ONNX with its CameraSettings input and matches eager."""

from __future__ import annotations

import warnings

import pytest
import torch

from models.networks import SmallDepthNet
from optics import CameraSettings

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnxscript")


def test_two_focus_network_exports_and_matches_eager(tmp_path):
    torch.manual_seed(0)
    net = SmallDepthNet("aif+focused", n_focus=2, depth_min=1.0, depth_max=8.0, width=8).eval()
    image, focused = torch.rand(1, 3, 32, 32), torch.rand(1, 2, 3, 32, 32)
    settings = CameraSettings(0.05, 1.4, [[2.0, 6.0]], 180e-6).to(torch.float32)
    path = tmp_path / "net.onnx"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(net, (image, focused, settings), path, dynamo=True, verbose=False)
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    values = [image, focused, *settings.tensors().values()]
    feeds = {i.name: v.numpy() for i, v in zip(session.get_inputs(), values, strict=True)}
    (out,) = session.run(None, feeds)
    with torch.no_grad():
        expected = net(image, focused, settings)
    torch.testing.assert_close(torch.from_numpy(out), expected, atol=1e-4, rtol=1e-4)
    # another camera through the same graph: the settings are inputs, not constants
    other = CameraSettings(0.035, 2.8, [[1.2, 3.0]], 100e-6).to(torch.float32)
    feeds = {i.name: v.numpy() for i, v in zip(
        session.get_inputs(), [image, focused, *other.tensors().values()], strict=True)}
    (out,) = session.run(None, feeds)
    with torch.no_grad():
        torch.testing.assert_close(torch.from_numpy(out), net(image, focused, other),
                                   atol=1e-4, rtol=1e-4)
