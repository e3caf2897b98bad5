"""Request and response models of POST /v1/vision/render and /v1/vision/motion (docs/vision.md,
docs/api.md "Vision"; the work: :mod:`service.operations.vision`)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Field, model_validator

from service.schemas import ID_PATTERN, Int, Name, Out, Strict, Vec3, alternatives
from vision.camera import DEFAULT_FOV_DEG, DEFAULT_SIZE_PX

#: Largest rendered frame [px a side] (the camera's own ceiling; ~1 s of CPU).
MAX_RENDER_SIZE_PX = 1024


def _range(lo: float, hi: float) -> Any:
    """A float in [lo, hi], for optional fields (the bounds before the union: plain JSON Schema)."""
    return Annotated[float, Field(ge=lo, le=hi)]


class PoseIn(Strict):
    """Where the capsule is: ``s_m`` along the phantom's GI-tract centreline (looking along the
    direction of travel), or ``position_m`` with a view ``direction`` (exactly one of the two)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True, json_schema_extra=alternatives([
        {"required": ["s_m"], "properties": {"s_m": {"type": "number"}},
         "not": {"anyOf": [{"required": ["position_m"]}, {"required": ["direction"]}, {"required": ["organ"]}]}},
        {"required": ["position_m", "direction"], "properties": {"position_m": {"type": "array"},
                                                                 "direction": {"type": "array"}},
         "not": {"required": ["s_m"]}}]))

    s_m: _range(0.0, 100.0) | None = Field(
        None, description="Arc length along the phantom's GI-tract centreline [m] (GET /v1/phantoms/{id}: "
        "`centrelines`); the camera sits on the line and looks along the direction of travel.")
    position_m: Vec3 | None = Field(None, description="Camera position [m] (phantom coordinates), inside a "
                                    "GI organ's lumen.")
    direction: Vec3 | None = Field(None, description="View direction [-] (normalised by the server; not zero).")
    organ: Name | None = Field(None, description="The organ whose lumen `position_m` must be in (default: any "
                               "organ of the phantom's GI-tract centreline, or any organ without one).")

    @model_validator(mode="after")
    def _one(self) -> "PoseIn":
        given = self.model_fields_set  # a key present with null counts, as the schema's oneOf says
        if self.s_m is not None and given & {"position_m", "direction", "organ"}:
            raise ValueError("give s_m, or position_m with direction, not both (organ goes with position_m)")
        if self.s_m is None and ("s_m" in given or self.position_m is None or self.direction is None):
            raise ValueError("give s_m, or position_m with direction (exactly one)")
        return self


class CameraIn(Strict):
    fov_deg: float = Field(DEFAULT_FOV_DEG, ge=10.0, le=220.0,
                           description="Full field of view of the equidistant fisheye [deg].")
    size_px: Int = Field(DEFAULT_SIZE_PX, ge=16, le=MAX_RENDER_SIZE_PX, description="Pixels a side (square) [-].")


class TextureIn(Strict):
    preset: Literal["auto", "default", "small_intestine", "colon", "stomach"] = Field(
        "auto", description="Mucosa preset; `auto`: the organ's (small bowel, colon, stomach, docs/vision.md).")
    fold_axis: Vec3 | None = Field(None, description="Axis the circular folds run across [-] (default: the "
                                   "organ's long axis); not zero.")
    seed: Int = Field(0, ge=0, le=2**31 - 1, description="Seed of the solid noise: the same seed, the same wall.")


class SensorIn(Strict):
    vignetting: float = Field(0.3, ge=0.0, le=1.0, description="Fall-off 1 - v (r/R)^2 at the rim [-].")
    full_well_electrons: _range(1.0, 1e7) | None = Field(None, description="Shot noise: electrons at full "
                                                         "scale [-] (none: no shot noise).")
    read_noise: float = Field(0.0, ge=0.0, le=1.0, description="Gaussian read noise, fraction of full scale [-].")
    salt_pepper: float = Field(0.0, ge=0.0, le=1.0, description="Fraction of pixels set black or white [-].")
    seed: Int = Field(0, ge=0, le=2**31 - 1, description="Noise seed [-].")


class RenderRequest(Strict):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True, json_schema_extra={"examples": [
        # 0.3 m along the default torso's 0.69 m GI-tract centreline (GET /v1/phantoms/torso: centrelines)
        {"phantom": "torso", "pose": {"s_m": 0.3}, "roll_deg": 0.0, "camera": {"fov_deg": 150.0, "size_px": 256}},
        {"phantom": "torso", "pose": {"position_m": [0.0, 0.0, 0.0], "direction": [0.0, 0.0, 1.0]}},
    ]})

    phantom: Annotated[str, Field(pattern=ID_PATTERN)] = Field(
        "torso", description="Phantom id (GET /v1/phantoms).")
    pose: PoseIn
    roll_deg: float = Field(0.0, ge=-360.0, le=360.0, description="Roll about the view direction [deg] (right-hand "
                            "rule; 0: the camera's up nearest the torso's head-ward +z).")
    camera: CameraIn = Field(default_factory=CameraIn, description="The fisheye.")
    texture: TextureIn = Field(default_factory=TextureIn, description="The procedural mucosa.")
    sensor: SensorIn = Field(default_factory=SensorIn, description="Sensor effects (gamma 2.2, 8 bit).")
    exposure: _range(1e-6, 1e9) | None = Field(None, description="Radiance to linear full scale [-]; none: "
                                               "automatic (98th luma percentile at 0.9).")


class PoseOut(Out):
    position_m: list[float] = Field(description="Camera position [m].")
    direction: list[float] = Field(description="Unit view direction [-].")
    up: list[float] = Field(description="Unit up vector of the image (rows grow against it) [-].")
    roll_deg: float = Field(description="Roll [deg].")
    s_m: float | None = Field(None, description="Arc length on the GI-tract centreline [m] (poses given by s_m).")
    organ: str = Field(description="Organ whose lumen holds the camera.")


class CameraOut(Out):
    fov_deg: float = Field(description="Field of view [deg].")
    size_px: int = Field(description="Pixels a side [-].")
    focal_px: float = Field(description="f of r = f theta [px per rad].")


class RenderResponse(Out):
    pose: PoseOut
    camera: CameraOut
    exposure: float = Field(description="Exposure used (the automatic one when none was given) [-].")
    wall_fraction: float = Field(description="Fraction of the image circle's pixels that see a wall [-].")
    median_depth_m: float | None = Field(None, description="Median distance to the wall over those pixels [m].")
    image_png_base64: str = Field(description="The frame, a PNG (8-bit RGB), base64.")


class MotionOptions(Strict):
    """The estimator's knobs (vision.motion.estimate_motion; docs/vision.md, "The estimator")."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True,
                              json_schema_extra={"examples": [{"estimate": "both", "bins": 64}]})

    estimate: Literal["both", "rotation", "scale"] = Field("both", description="What to estimate.")
    strategy: Literal["joint", "in_turn"] = Field("joint", description="Bracketing: a joint grid, or in turn "
                                                  "(the thesis' order).")
    search: Literal["fibonacci", "golden"] = Field("fibonacci", description="1-D maximiser.")
    bins: Int = Field(64, ge=2, le=1024, description="Grey-level bins per frame [-].")
    cutoff: _range(0.01, 0.7071) | None = Field(0.15, description="Butterworth cut-off [cycles/px] (null: no "
                                                "pre-filter).")
    order: Int = Field(2, ge=1, le=16, description="Butterworth order [-].")
    kernel_a: float = Field(-1.0, ge=-3.0, le=0.0, description="Cubic-convolution a [-] (-1: thesis Eq 3.9, "
                            "-0.5: Keys).")
    rotation_range_deg: list[Annotated[float, Field(ge=-180.0, le=180.0)]] = Field(
        [-90.0, 90.0], min_length=2, max_length=2, description="Rotations searched, [low, high] [deg].")
    scale_range: list[Annotated[float, Field(ge=0.05, le=20.0)]] | None = Field(
        None, min_length=2, max_length=2, description="Scales searched, [low, high] [-] (default 0.5-2 for both, "
        "0.15-5 for scale alone).")
    rotation_tolerance_deg: float = Field(0.005, ge=1e-4, le=1.0, description="Final rotation bracket [deg].")
    scale_tolerance: float = Field(0.0005, ge=1e-5, le=1.0, description="Final bracket in log scale [-].")
    initial_rotation_deg: float = Field(0.0, ge=-180.0, le=180.0, description="Rotation held when estimating "
                                        "scale alone [deg].")
    initial_scale: float = Field(1.0, ge=0.05, le=20.0, description="Scale held when estimating rotation alone [-].")
    max_pixels: Int = Field(2**17, ge=1024, le=2**20, description="Pixels compared per pyramid level at most [-].")


class MotionResponse(Out):
    rotation_deg: float = Field(description="Rotation of the moving frame's content, counter-clockwise as "
                                "displayed = the capsule's roll increment [deg].")
    scale: float = Field(description="Magnification about the optical axis [-] (> 1: advancing).")
    advance_m: float | None = Field(None, description="Advance along the view direction that gives this scale "
                                    "in the reference frame's rendered geometry [m] (with `geometry` only).")
    advance_note: str | None = Field(None, description="Why advance_m is null although geometry was given.")
    mutual_information: float = Field(description="MI reached, Eq 3.2 at full resolution [nats].")
    iterations: int = Field(description="Bracket reductions of the 1-D searches [-].")
    evaluations: int = Field(description="MI evaluations over all pyramid levels [-].")
    levels: int = Field(description="Pyramid levels [-].")
    width_px: int = Field(description="Frame width [px].")
    height_px: int = Field(description="Frame height [px].")
    options: MotionOptions = Field(description="The options used (defaults filled in).")
