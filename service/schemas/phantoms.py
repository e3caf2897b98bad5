"""Models of the catalogue and of uploads (``docs/api.md``): tissues, phantoms, scenarios, and the
manifest of POST /v1/phantoms."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import ConfigDict, Field

from service.schemas import Name, Out, Strict, Vec3
from service.schemas import constants as gltf  # the upload manifest's rules (raytrace.body.gltf's)


class TissueOut(Out):
    name: str
    relative_permittivity: float = Field(description="eps_r' [-].")
    conductivity_s_per_m: float = Field(description="Effective conductivity [S/m].")
    loss_tangent: float = Field(description="sigma / (w eps0 eps_r') [-].")
    phase_velocity_m_per_s: float = Field(description="Phase velocity [m/s].")
    attenuation_db_per_m: float = Field(description="Attenuation [dB/m].")
    wavelength_m: float = Field(description="Wavelength in the tissue [m].")


class TissuesResponse(Out):
    frequency_hz: float = Field(description="Frequency [Hz].")
    tissues: list[TissueOut]


class OrganOut(Out):
    name: str
    tissue: str | None = Field(None, description="Gabriel 1996 tissue, or null for an explicit medium.")
    relative_permittivity: float | None = Field(None, description="Explicit medium: eps_r' [-].")
    conductivity_s_per_m: float | None = Field(None, description="Explicit medium: conductivity [S/m].")
    triangles: int
    parent: str = Field(description="Containing organ, or `air`.")
    bounds_m: list[Vec3] = Field(description="Axis-aligned bounds [[xmin,ymin,zmin],[xmax,ymax,zmax]] [m].")


class SiteOut(Out):
    kind: Literal["capsule", "sensor"]
    position_m: Vec3 = Field(description="Position [m].")
    medium: str


class PhantomSummary(Out):
    id: str
    name: str
    description: str = ""
    builtin: bool
    triangles: int
    bounds_m: list[Vec3] = Field(description="Axis-aligned bounds [m].")


class PhantomOut(PhantomSummary):
    organs: list[OrganOut]
    sites: dict[str, SiteOut]


class PhantomsResponse(Out):
    phantoms: list[PhantomSummary]


class ScenarioOut(Out):
    id: str
    description: str
    phantom: str
    frequency_hz: float | None = Field(None, description="Carrier [Hz].")
    notes: str = Field("", description="Assumptions and what the case is meant to show.")
    request: dict[str, Any] = Field(description="The channel request fields this scenario supplies.")


class ScenariosResponse(Out):
    scenarios: list[ScenarioOut]


class ManifestTissue(Strict):
    tissue: Literal[gltf.TISSUE_NAMES] = Field(  # type: ignore[valid-type]
        description="Gabriel 1996 tissue (GET /v1/tissues)."
    )


class ManifestMedium(Strict):
    relative_permittivity: float = Field(ge=1.0, le=gltf.MAX_PERMITTIVITY, description="Explicit medium eps_r' [-].")
    conductivity_s_per_m: float = Field(
        0.0, ge=0.0, le=gltf.MAX_CONDUCTIVITY_S_PER_M, description="Explicit medium conductivity [S/m]."
    )


class ManifestSite(Strict):
    kind: Literal["capsule", "sensor"] | None = Field(
        None, description="Required for a site inside tissue (capsule, or a contact sensor in the skin); "
        "without it a site in air is a sensor."
    )
    position_m: Vec3 = Field(description="Position [m] (always metres, whatever `units`).")


class ManifestCentrelinePiece(Strict):
    organ: Name = Field(description="The organ (mesh node) this piece runs inside.")
    points: list[Vec3] = Field(min_length=2, max_length=20_000, description="Polyline vertices in `units`.")


class ManifestCentreline(Strict):
    pieces: list[ManifestCentrelinePiece] = Field(
        min_length=1, max_length=256, description="Pieces in travel order; the position jumps between pieces.")


class Manifest(Strict):
    """The JSON part of an upload (docs/api.md "POST /v1/phantoms").

    This model documents the manifest in the API schema; the one validator is
    ``raytrace.body.gltf.validate_manifest`` (with the loader's checks against the
    mesh), whose constants these bounds are."""

    model_config = ConfigDict(  # Strict's rules are inherited; only the schema extras here
        json_schema_extra={
            "examples": [
                {
                    "name": "box with a sphere",
                    "units": "m",
                    "organs": {
                        "body": {"tissue": "muscle"},
                        "organ": {"relative_permittivity": 11.6, "conductivity_s_per_m": 0.08},
                    },
                    "sites": {
                        "capsule": {"kind": "capsule", "position_m": [0.0, 0.0, 0.01]},
                        "sensor": [0.0, -0.15, 0.0],
                    },
                }
            ]
        },
    )

    name: str = Field(min_length=1, max_length=gltf.MAX_NAME_CHARS, description="Human name of the phantom.")
    description: str = Field("", max_length=gltf.MAX_DESCRIPTION_CHARS)
    units: Literal[tuple(gltf.UNITS)] = Field(  # type: ignore[valid-type]
        description=f"Unit of the mesh coordinates (and of `[x, y, z]` sites); the mesh's largest extent in "
        f"metres must lie in {gltf.MIN_EXTENT_M:g}-{gltf.MAX_EXTENT_M:g} m."
    )
    organs: dict[Name, ManifestTissue | ManifestMedium] = Field(
        min_length=1, max_length=gltf.MAX_ORGANS, description="Mesh node name -> medium (a tissue, or an explicit one)."
    )
    sites: dict[Name, Vec3 | ManifestSite] = Field(
        default_factory=dict,
        max_length=gltf.MAX_SITES,
        description="Site name -> [x, y, z] in `units` (a site in air: a sensor), or {kind, position_m} with the "
        "position in metres (kind required inside tissue).",
    )
    centrelines: dict[Name, ManifestCentreline] = Field(
        default_factory=dict,
        max_length=16,
        description="Named paths through the organs (the GI tract: `gi_tract`); a capsule position may be given by "
        "arc length along one (sweeps). Every point must lie inside its piece's organ.",
    )


class UploadResponse(PhantomOut):
    pass


class BuildError(Out):
    loc: list[str | int] = Field(description="Where the problem is, as in a 422's detail (the archive's manifest "
                                             "entry, file, organ or label).")
    msg: str = Field(description="Why.")


class PhantomBuildStatus(Out):
    """A phantom build job (POST /v1/phantoms with an `archive`; docs/phantoms.md, "Over HTTP")."""

    id: str = Field(description="Build id (`pb-` + 16 hex digits).")
    name: str = Field(description="The manifest's name.")
    state: Literal["queued", "running", "done", "failed", "cancelled"]
    progress: float = Field(ge=0.0, le=1.0, description="Fraction of the build done.")
    message: str = Field(description="What the build is doing now.")
    phantom_id: str | None = Field(None, description="The stored phantom (`up-...`), once `done`.")
    error: BuildError | None = Field(None, description="Why a `failed` build was refused.")
    created_at: float | None = None
    started_at: float | None = None
    finished_at: float | None = None
    cancel_requested: bool = False
    deleted: bool = Field(False, description="DELETE of a finished build: its record was deleted.")
    report: dict[str, Any] | None = Field(None, description="The build report (per organ triangles, volume, "
                                                             "repairs; generated layers; tracts; sensors), once "
                                                             "`done`.")


class PhantomBuildSummary(Out):
    id: str
    name: str
    state: Literal["queued", "running", "done", "failed", "cancelled"]
    progress: float
    phantom_id: str | None = None
    created_at: float | None = None


class PhantomBuildList(Out):
    builds: list[PhantomBuildSummary]
