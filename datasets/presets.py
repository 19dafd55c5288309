"""Camera presets per dataset (DESIGN section 7): the virtual camera that synthesises focus.

Every `pixel_pitch` is the *effective* pitch at the dataset's native image resolution (metres);
loaders that resize scale it by the resize factor (see `datasets.transforms`). Where the
paper gives no camera, our choice keeps the image geometry (focal length in pixels `f / pitch`
equals the dataset's calibrated one) and picks an aperture that gives a few pixels of blur.

==============  ========  =========  ===========  ===========  ======  ==============================
preset          f (mm)    pitch(um)  focus (m)    f-number     cap(m)  source
==============  ========  =========  ===========  ===========  ======  ==============================
`nyu`         35        22.4       2, 8         2.8          10      paper (5.6 um x 4 at 640x480)
`kitti`       50        69.3       8, 30        1.4          80      ours; f_px = 721.5 at 1242x375
`make3d`      50        33.8       8, 30        1.4          70      ours; f_px ~ 1480 at 1704 wide
`dslr`        35        (per set)  1.7          2.8          10      Carvalho et al. 2018
`middlebury`  85        (per set)  2.5, 4       1.4          10      ours; pitch = f / f_px (calib)
==============  ========  =========  ===========  ===========  ======  ==============================

`dslr` and `middlebury` pitches depend on each image's resolution or calibration; the loaders
fill them in. Light fields have a calibration of their own (`datasets.LightFieldCalibration`).
"""

from __future__ import annotations

from .focus import CameraPreset

#: NYU Depth v2 (paper): 35 mm, Kinect RGB pitch 5.6 um x 4 at 640x480, focus 2 m and 8 m.
NYU = CameraPreset(0.035, 22.4e-6, focus_distances=(2.0, 8.0), f_numbers=(2.8,), depth_cap=10.0)

#: KITTI: 50 mm at f/1.4, pitch chosen so that f / pitch = 721.5 px (the KITTI calibration).
KITTI = CameraPreset(
    0.05, 0.05 / 721.5, focus_distances=(8.0, 30.0), f_numbers=(1.4,), depth_cap=80.0
)

#: Make3D: 50 mm at f/1.4, about 60 degrees of horizontal field of view on 1704-pixel-wide photos.
MAKE3D = CameraPreset(
    0.05, 0.05 / 1480.0, focus_distances=(8.0, 30.0), f_numbers=(1.4,), depth_cap=70.0
)

#: DSLR (Carvalho et al. 2018): 35 mm, focus about 1.7 m, f/2.8 wide open (f/8 is the reference).
#: The pixel pitch here is the full-frame sensor's (Nikon D810, 4.88 um); the loader scales it
#: to the stored photos' width.
DSLR = CameraPreset(0.035, 4.88e-6, focus_distances=(1.7,), f_numbers=(2.8,), depth_cap=10.0)

#: Middlebury: 85 mm at f/1.4, focus 2.5 m and 4 m; the pitch is per scene, `f / f_px`.
MIDDLEBURY = CameraPreset(
    0.085, 0.085 / 994.978, focus_distances=(2.5, 4.0), f_numbers=(1.4,), depth_cap=10.0
)

#: Every preset by dataset name.
PRESETS: dict[str, CameraPreset] = {
    "nyu": NYU,
    "kitti": KITTI,
    "make3d": MAKE3D,
    "dslr": DSLR,
    "middlebury": MIDDLEBURY,
}
