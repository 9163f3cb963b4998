"""The seams.json format as pydantic models, and its JSON Schema (spec: capture-format.md, "seams.json").

``weldcell schema seams`` prints :func:`seams_json_schema`. The models describe the file; the writer is
:func:`perception.seams.seams_to_json`. Extra keys are allowed at every level (readers ignore them), so
weldcell's own additions (``surfaces``, ``fanuc_xyzwpr_mm_deg``, ``ur_pose``, ``info``) are described as
optional fields and anything else passes.

Units are SI (``"units": "m"``): points and pose positions in metres, quaternions scalar-last
``[qx, qy, qz, qw]``, times in seconds. The FANUC and UR extras are in the robots' units (mm and deg;
m and rotation-vector radians), as their names say.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator
from pydantic.json_schema import SkipJsonSchema

FORMAT_VERSION = "1.1"
"""Written into every seams.json. A reader accepts 1.x (and files from before the field, read as 1.0)."""

UNITS = "m"

SCHEMA_ID = "urn:weldcell:seams.json:1.1"

Point3 = Annotated[tuple[float, float, float], Field(description="[x, y, z] in metres, in the file's frame")]
Pose7 = Annotated[
    tuple[float, float, float, float, float, float, float],
    Field(description="[x, y, z, qx, qy, qz, qw]: position in metres, unit quaternion scalar-last"),
]
Joint = Literal["fillet", "inside_corner", "lap", "v_groove", "butt"]


class SeamModel(BaseModel):
    """One seam: its welding path and the torch pose at each path point."""

    model_config = ConfigDict(extra="allow", title="Seam")

    id: int = Field(ge=0)
    kind: Literal["linear", "curved"]
    joint: Joint | SkipJsonSchema[None] = Field(default=None, description="joint type, when the detector names it")
    points: list[Point3] = Field(
        min_length=2, description="the welding path, ordered along the seam, metres (default spacing <= 5 mm)"
    )
    poses: list[Pose7] = Field(
        description="torch pose at each path point: z axis from the torch into the joint, x axis along travel"
    )
    length_m: float = Field(ge=0.0, description="length of the seam, metres")
    confidence: float = Field(ge=0.0, le=1.0)
    surfaces: Annotated[list[int], Field(min_length=2, max_length=2)] | SkipJsonSchema[None] = Field(
        default=None, description="the two surface labels (prompt indices) that meet"
    )
    fanuc_xyzwpr_mm_deg: list[list[float]] | SkipJsonSchema[None] = Field(
        default=None, description="the poses as FANUC XYZWPR: millimetres and degrees"
    )
    ur_pose: list[list[float]] | SkipJsonSchema[None] = Field(
        default=None, description="the poses as UR pose vectors: metres and a rotation vector in radians"
    )

    @model_validator(mode="after")
    def _one_pose_per_point(self) -> SeamModel:
        # not expressible in JSON Schema; checked when a file is read through the model
        if len(self.poses) != len(self.points):
            raise ValueError(f"seam {self.id}: {len(self.poses)} poses for {len(self.points)} points")
        return self


class SeamsFileModel(BaseModel):
    """seams.json: the seams of one capture, in the camera frame or (with pose.json) the robot base frame."""

    model_config = ConfigDict(
        extra="allow",
        title="weldcell seams.json",
        json_schema_extra={"$id": SCHEMA_ID, "$schema": "https://json-schema.org/draft/2020-12/schema"},
    )

    format_version: Literal["1.1"] = Field(description="seams.json format version")
    units: Literal["m"] = Field(description="length unit of points and pose positions")
    frame: Literal["camera", "base"] = Field(description="frame of every point and pose: camera optical or robot base")
    seams: list[SeamModel]
    points: dict[str, Annotated[int, Field(ge=0)]] | SkipJsonSchema[None] = Field(
        default=None, description="point counts per stage: raw, cropped, downsampled"
    )
    timing_s: dict[str, Annotated[float, Field(ge=0.0)]] | SkipJsonSchema[None] = Field(
        default=None, description="seconds per stage: coarse, fine, total"
    )


def seams_json_schema() -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of seams.json."""
    return _drop_null_defaults(SeamsFileModel.model_json_schema())


def _drop_null_defaults(node: Any) -> Any:
    # an optional field's "default": null would contradict its type in the schema; absent means absent
    if isinstance(node, dict):
        return {k: _drop_null_defaults(v) for k, v in node.items() if not (k == "default" and v is None)}
    if isinstance(node, list):
        return [_drop_null_defaults(v) for v in node]
    return node
