"""The one registry of PSF (aperture) names: parse and write aperture specs.

A spec is a short string used everywhere a PSF shape is named: camera JSON files, calibration,
training configs and the command line.

| spec | aperture |
|---|---|
| `gaussian` | `Gaussian(0.5)`: sigma = 0.5 x CoC diameter (the paper's choice) |
| `gaussian:S` | `Gaussian(S)`: sigma = S x CoC diameter |
| `disk` | `Disk()`: a pillbox with an anti-aliased edge |
| `polygon:N` | `Polygon(N)`: an N-blade aperture |
| `polygon:N:R` | `Polygon(N, rotation=R)`, R in radians |

A `Mask` (a measured PSF image) has no spec: pass the `Mask` object itself. Where nobody names
one, the PSF is `DEFAULT_APERTURE`; where a real lens's photos are read and nothing says more
(no calibration), `LENS_APERTURE`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from .aperture import Aperture, Disk, Gaussian, Polygon

#: Families a spec may name, with the arguments each takes after its name.
APERTURE_FAMILIES: dict[str, str] = {
    "gaussian": "gaussian[:SCALE]",
    "disk": "disk",
    "polygon": "polygon:N_BLADES[:ROTATION_RADIANS]",
}

#: The PSF when nobody says: the paper's Gaussian, sigma = 0.5 x CoC diameter (`Gaussian(0.5)`).
DEFAULT_APERTURE = "gaussian:0.5"
#: The PSF of a real lens when nothing says more (photos without a calibration, the pairs a
#: calibration fits, renders of a real scene): the iris's disk. The paper's Gaussian is a
#: training choice; a real lens's blur has a sharp edge.
LENS_APERTURE = "disk"


def _spec_error(spec: object, why: str) -> ValueError:
    allowed = ", ".join(APERTURE_FAMILIES.values())
    return ValueError(f"aperture spec {spec!r} is not valid ({why}); expected one of: {allowed}")


#: Each family's aperture, and the names of the arguments it takes after its name (required first).
_BUILDERS: dict[str, tuple[type[Aperture], tuple[str, ...], int]] = {
    "gaussian": (Gaussian, ("scale",), 0),
    "disk": (Disk, (), 0),
    "polygon": (Polygon, ("n_blades", "rotation"), 1),
}


def _number(text: str, what: str) -> float | int:
    """A spec's argument as a finite number (an int where it is a whole one, for `n_blades`)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise ValueError(f"{what} {text!r} is not a finite number")
    return int(value) if what == "n_blades" and value == int(value) else value


def parse_aperture(spec: str | Aperture) -> Aperture:
    """Build the aperture a spec names (an `Aperture` is returned as it is).

    Args:
        spec: e.g. `"gaussian"`, `"gaussian:0.5"`, `"disk"`, `"polygon:6"`, `"polygon:6:0.3"`.

    Raises:
        ValueError: for an unknown family or bad arguments (the message lists what is allowed).

    Example:
        >>> parse_aperture("polygon:6")
        Polygon(n_blades=6, rotation=0.0)
        >>> parse_aperture("gaussian:0.25").scale
        tensor(0.2500)
        >>> parse_aperture("disk:2")
        Traceback (most recent call last):
        ...
        ValueError: aperture spec 'disk:2' is not valid (disk takes 0 to 0 arguments, got 1); expected one of: gaussian[:SCALE], disk, polygon:N_BLADES[:ROTATION_RADIANS]
    """
    if isinstance(spec, Aperture):
        return spec
    if not isinstance(spec, str):
        raise TypeError(f"aperture must be a spec string or an Aperture, got {type(spec).__name__}")
    family, *args = spec.strip().lower().split(":")
    build, names, required = _BUILDERS.get(family, (None, (), 0))
    if build is None or not required <= len(args) <= len(names):
        raise _spec_error(spec, f"unknown family {family!r}" if build is None else
                          f"{family} takes {required} to {len(names)} arguments, got {len(args)}")
    try:  # the ranges are the constructors' own (MAX_GAUSSIAN_SCALE, MAX_BLADES)
        return build(*(_number(text, what) for text, what in zip(args, names, strict=False)))
    except ValueError as error:
        raise _spec_error(spec, str(error)) from None


def aperture_spec(aperture: Aperture | str) -> str:
    """The spec string of an aperture (inverse of `parse_aperture`).

    Raises:
        ValueError: for a `Mask` or any aperture without a spec.

    Example:
        >>> from optics import Disk, Gaussian
        >>> aperture_spec(Gaussian(0.5)), aperture_spec(Disk())
        ('gaussian:0.5', 'disk')
    """
    if isinstance(aperture, str):
        return aperture_spec(parse_aperture(aperture))
    if isinstance(aperture, Gaussian):
        return f"gaussian:{float(aperture.scale.detach()):.6g}"
    if isinstance(aperture, Polygon):
        rotation = float(aperture.rotation)
        return f"polygon:{aperture.n_blades}" + (f":{rotation:.6g}" if rotation else "")
    if type(aperture) is Disk:
        return "disk"
    raise ValueError(
        f"a {type(aperture).__name__} aperture has no spec string; pass the object itself "
        f"(specs exist for {', '.join(APERTURE_FAMILIES)})"
    )


def aperture_from_json(value: str | Mapping[str, Any]) -> Aperture:
    """Read the `psf` entry of a camera JSON: a spec string, or the older
    `{"family": ..., "scale"/"n_blades"/"rotation": ...}` object."""
    if isinstance(value, Mapping):
        family = str(value.get("family", ""))
        if family == "gaussian":
            return parse_aperture(f"gaussian:{value.get('scale', 0.5)}")
        if family == "polygon":
            return parse_aperture(f"polygon:{value.get('n_blades')}:{value.get('rotation', 0.0)}")
        return parse_aperture(family)
    return parse_aperture(value)
