"""Depth-sensor presets: the noise model of the simulated cameras, named after real sensors.

A preset describes what the camera gets wrong, not where it is: Gaussian depth noise, missing
pixels at depth edges, depth quantisation, and the ground sampling (pixel footprint on the floor).
The numbers are typical of the sensor class at a working distance of about 1-1.5 m:

- ``none`` (alias ``perfect``): an ideal sensor. Perception then recovers the exact heightmap and
  the exact object sizes, which is what the tests check and what "noise off" means in the bench.
- ``structured-light``: an industrial structured-light camera (Zivid / Photoneo class): about
  1 mm depth noise, few missing pixels at edges (the projector/camera baseline shadows a small
  band beside tall edges), 0.5 mm depth steps.
- ``stereo``: a consumer active-stereo camera (RealSense D4xx class): about 1-2 % of the distance,
  i.e. 5-10 mm at 0.5-1 m (we take 6 mm), many invalid pixels along depth discontinuities (the
  matcher fails where one view is occluded), and coarse 2 mm disparity-derived depth steps.

The pixel footprint is 5 mm for all of them (a 1280-pixel-wide image over ~6 m would be coarser;
a real cell keeps the camera close): an odd number of pixels (5) per 25 mm cell puts one pixel on
each cell centre, which makes the per-cell median agree with the centre-sampled rasteriser.
The buffer (the shown boxes lying together on a table or in a tote) is imaged by a second camera
closer to it, at ``buffer_pixel_mm``: a 75 mm box then spans about 37 pixels, so its yaw is found
within a degree or two and the grooves between touching boxes span several pixels.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from packlab.core.errors import ConfigError


@dataclass(frozen=True, slots=True)
class SensorPreset:
    """Noise model of a top-down depth camera (all lengths in mm)."""

    name: str
    depth_noise_mm: float  # sigma of zero-mean Gaussian noise added to each pixel's depth
    edge_dropout: float  # fraction (0..1) of depth-edge pixels returned as missing (NaN)
    quantisation_mm: float  # depth is rounded to multiples of this; 0 = continuous
    pixel_mm: float = 5.0  # ground sampling distance: pixel pitch on the imaged plane
    camera_height_mm: float = 1500.0  # camera above the container rim / table surface
    buffer_pixel_mm: float = 2.0  # pixel pitch of the buffer camera on the table (see camera)
    #: Neighbouring heightmap cells closer than this (mm) are taken as one flat top and given
    #: their common median (``perception.flatten_tops``): about 5 sigma of one cell's median
    #: noise, far below a box's height. 0 (noise-free): off.
    flat_tolerance_mm: float = 0.0

    def __post_init__(self) -> None:
        checks = (
            ("depth_noise_mm", self.depth_noise_mm >= 0),
            ("edge_dropout", 0.0 <= self.edge_dropout <= 1.0),
            ("quantisation_mm", self.quantisation_mm >= 0),
            ("pixel_mm", self.pixel_mm > 0),
            ("camera_height_mm", self.camera_height_mm > 0),
            ("buffer_pixel_mm", 0 < self.buffer_pixel_mm <= 10),
            ("flat_tolerance_mm", self.flat_tolerance_mm >= 0),
        )
        for field, ok in checks:
            if not ok:
                value = getattr(self, field)
                raise ConfigError(f"sensor preset {self.name!r}: {field} = {value!r}: out of range")

    def scaled(self, factor: float) -> SensorPreset:
        """The same sensor with noise, dropout and quantisation scaled (noise-sweep experiments)."""
        return replace(
            self,
            name=f"{self.name}x{factor:g}",
            depth_noise_mm=self.depth_noise_mm * factor,
            edge_dropout=min(1.0, self.edge_dropout * factor),
            quantisation_mm=self.quantisation_mm * factor,
            flat_tolerance_mm=self.flat_tolerance_mm * factor,
        )


_NONE = SensorPreset("none", depth_noise_mm=0.0, edge_dropout=0.0, quantisation_mm=0.0)

#: The presets by name; the keys of ``core.choices.NoisePreset`` plus the alias ``perfect``.
SENSOR_PRESETS: dict[str, SensorPreset] = {
    "none": _NONE,
    "perfect": replace(_NONE, name="perfect"),
    "structured-light": SensorPreset(
        "structured-light",
        depth_noise_mm=1.0,
        edge_dropout=0.05,
        quantisation_mm=0.5,
        flat_tolerance_mm=1.5,
    ),
    "stereo": SensorPreset(
        "stereo", depth_noise_mm=6.0, edge_dropout=0.3, quantisation_mm=2.0, flat_tolerance_mm=7.5
    ),
}


def sensor_preset(preset: SensorPreset | str) -> SensorPreset:
    """A preset given itself or by name; an unknown name is a ConfigError listing the names."""
    if isinstance(preset, SensorPreset):
        return preset
    try:
        return SENSOR_PRESETS[preset]
    except KeyError:
        names = ", ".join(SENSOR_PRESETS)
        raise ConfigError(f"noise preset = {preset!r}: unknown; available: {names}") from None
