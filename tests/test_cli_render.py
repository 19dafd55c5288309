import matplotlib.image as mpimg

from defocus.cli import main


def test_render_writes_focus_sweep_of_the_motorcycle(tmp_path):
    assert main(["render", "--out", str(tmp_path), "--scale", "0.25", "--focus-distance",
                 "2.2", "5.0"]) == 0
    figure = mpimg.imread(tmp_path / "focus_sweep.png")
    assert figure.ndim == 3 and figure.shape[0] > 100 and figure.shape[1] > 300


def test_focus_sweep_blurs_what_is_out_of_focus():
    from datasets.middlebury import motorcycle_focus_sweep

    sweep = motorcycle_focus_sweep([2.2, 5.0], 0.085, 1.4, "disk", "scatter", 0.25)
    image, depth = sweep["image"], sweep["depth"]
    near = depth < 2.6  # the floor in front of the motorcycle
    far = depth > 4.5  # the back wall
    focus_distances = sweep["settings"].focus_distance.tolist()
    for focus, render, coc in zip(focus_distances, sweep["renders"], sweep["coc_px"], strict=True):
        in_focus, out_of_focus = (near, far) if focus < 3 else (far, near)
        assert coc[in_focus].mean() < coc[out_of_focus].mean()
        error = (render - image).abs().mean(0, keepdim=True)
        assert error[in_focus].mean() < error[out_of_focus].mean()
