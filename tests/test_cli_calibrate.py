"""End-to-end test of ``defocus calibrate`` on synthetic Bayer DNG pairs."""

from __future__ import annotations

import json

import pytest
from _synthetic_dng import synthetic_camera, write_pairs

from defocus.cli import main
from optics import Camera, Disk


@pytest.mark.slow
def test_cli_calibrate_writes_loadable_fit(tmp_path, capsys):
    files = write_pairs(tmp_path, synthetic_camera(Disk()), (1.2, 1.5, 4.0), size=64, seed=20)
    argv = ["calibrate"]
    for sharp, blurred, distance in files:
        argv += ["--pair", str(sharp), str(blurred), str(distance)]
    # f-number and pixel pitch come from the metadata unless asked to fit: fit the f-number.
    argv += ["--fit", "f_number", "--out", str(tmp_path / "fit.json"), "--adam-steps", "30"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "focal_length: from the metadata" in out and "pixel_pitch: from the metadata" in out
    assert "focus_distance" in out and "fitted" in out
    data = json.loads((tmp_path / "fit.json").read_text())
    assert {"focus_distance", "f_number", "focal_length", "pixel_pitch", "aperture"} <= set(data)
    assert set(data["uncertainty"]) == {"focus_distance", "f_number"}
    assert data["f_number"] == pytest.approx(4.0, rel=0.02)
    assert data["focus_distance"] == pytest.approx(2.0, rel=0.02)
    assert data["focal_length"] == 0.025 and data["pixel_pitch"] == pytest.approx(5e-6)
    camera = Camera.from_json(tmp_path / "fit.json")
    assert float(camera.lens.f_number) == pytest.approx(data["f_number"])
    assert (tmp_path / "fit.png").stat().st_size > 1000


def test_cli_calibrate_bad_inputs(tmp_path, capsys):
    files = write_pairs(tmp_path, synthetic_camera(Disk()), (1.5,), size=32)
    sharp, blurred, _ = files[0]
    assert main(["calibrate", "--pair", str(sharp), str(blurred), "0"]) == 2
    assert "distance must be > 0 metres" in capsys.readouterr().err
    assert main(["calibrate", "--pair", str(sharp), str(tmp_path / "gone.dng"), "2"]) == 2
    assert "gone.dng" in capsys.readouterr().err
    # f-number and pixel pitch both from the metadata and the focus distance given: nothing left.
    argv = ["calibrate", "--pair", str(sharp), str(blurred), "1.5", "--focus-distance", "2"]
    assert main(argv) == 2
    assert "every parameter is fixed" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["zedd", "mobile_depth"])
def test_calibrate_refuses_a_focal_stack_benchmark_at_the_door(tmp_path, capsys, name):
    """A focal-stack benchmark has no aperture pairs to fit: refused in one line naming
    --data and the benchmark, before its folder is read (it used to fail on "0 depth bins")."""
    assert main(["calibrate", "--data", name, "--root", str(tmp_path / "missing"),
                 "--out", str(tmp_path / "fit.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("defocus calibrate: error: --data must be a dataset of real "
                          "photos with depth") and "\n" not in err, err
    assert f"got {name!r} (a focal-stack benchmark" in err, err
    assert not (tmp_path / "fit.json").exists()
