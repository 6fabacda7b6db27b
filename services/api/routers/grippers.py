from __future__ import annotations

import json
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Path, Request, Response
from starlette.datastructures import UploadFile

from graspgen.gripper_geometry import MESH_ROLES
from services.common.settings import Settings

from ..crud import grippers as crud
from ..deps import PagingDep, ReadDep, ReadSessionDep, SessionDep, SettingsDep, StorageDep, WriteDep
from ..http import IMMUTABLE, blob_response
from ..problems import ApiError
from ..schemas import (
    GRIPPER_SPEC_EXAMPLE,
    ID_MAX,
    SLUG,
    SUCTION_SPEC_EXAMPLE,
    GripperOut,
    GripperPage,
    GripperVersionOut,
)
from . import problems

router = APIRouter(prefix="/v1/grippers", tags=["grippers"])

NameParam = Annotated[str, Path(pattern=SLUG, examples=["pgn-80"])]
VersionParam = Annotated[int, Path(ge=1, le=ID_MAX, examples=[1])]

_MEDIA = {"stl": "model/stl", "obj": "model/obj", "glb": "model/gltf-binary", "ply": "application/x-ply"}
_CHUNK = 1024 * 1024
_MAX_PARTS = 4 * len(MESH_ROLES)

#: the two bodies POST /v1/grippers takes, documented by hand: the route reads the body itself (which one it is
#: follows from the Content-Type), so that one path serves both
_SPEC_BODY = {
    "required": True,
    "content": {
        "application/json": {
            "schema": {"allOf": [{"$ref": "#/components/schemas/AnyGripperSpec"}]},
            "examples": {
                "parallel": {"summary": "a parallel-jaw gripper (boxes)", "value": GRIPPER_SPEC_EXAMPLE},
                "suction": {"summary": "a suction cup on a cylinder tool", "value": SUCTION_SPEC_EXAMPLE},
            },
        },
        "multipart/form-data": {
            "schema": {
                "type": "object",
                "required": ["spec"],
                "properties": {
                    "spec": {
                        "type": "string",
                        "description": "the gripper spec JSON (CONTRACT.md, either kind), with `geometry` naming its "
                        "mesh files",
                    }
                },
                "additionalProperties": {
                    "type": "string",
                    "format": "binary",
                    "description": "one file part per path the spec's geometry names (finger, finger_left, body; "
                    "a suction cup's: body), "
                    "the part's field name being that path, e.g. `finger.stl`; STL, OBJ, PLY, OFF or GLB, each at "
                    "most the upload limit and 200,000 triangles",
                },
            },
            "encoding": {"spec": {"contentType": "application/json"}},
        },
    },
}


async def _spec_and_files(request: Request, settings: SettingsDep) -> tuple[Any, dict[str, bytes] | None]:
    """The body: a spec as JSON, or multipart with the spec in field `spec` and one file part per mesh file."""
    if not request.headers.get("content-type", "").lower().startswith("multipart/form-data"):
        body = await request.body()
        try:
            data = json.loads(body)
        except (ValueError, UnicodeDecodeError) as exc:
            raise ApiError(422, "validation-error", f"the body is not valid JSON: {exc}") from None
        if not isinstance(data, dict):  # as the JSON body's schema says (and said before the multipart form)
            raise ApiError(422, "validation-error", "body: Input should be a valid dictionary (the gripper spec)")
        return data, None
    return await _multipart(request, settings)


async def _multipart(request: Request, settings: Settings) -> tuple[Any, dict[str, bytes]]:
    # more parts than a spec can name are let through to be refused by name (422); the body's size is bounded by
    # BodyLimitMiddleware, each file by max_upload_bytes below
    async with request.form(max_files=_MAX_PARTS, max_fields=_MAX_PARTS, max_part_size=settings.max_json_bytes) as form:
        spec_field = form.getlist("spec")
        if len(spec_field) != 1:
            raise ApiError(422, "invalid-gripper", "the multipart body needs one field `spec` (the JSON)", field="spec")
        text: UploadFile | str | bytes = spec_field[0]
        if isinstance(text, UploadFile):  # sent as a file part (curl -F spec=@spec.json)
            text = await _read_limited(text, "spec", settings.max_json_bytes)
        try:
            spec = json.loads(text)
        except (ValueError, UnicodeDecodeError) as exc:
            raise ApiError(422, "invalid-gripper", f"field `spec` is not valid JSON: {exc}", field="spec") from None
        files: dict[str, bytes] = {}
        for key, value in form.multi_items():
            if key == "spec":
                continue
            if not isinstance(value, UploadFile):
                raise ApiError(422, "invalid-gripper", f"field {key!r} must be a file part", field=key)
            if key in files:
                raise ApiError(422, "invalid-gripper", f"file {key!r} was sent twice", field=key)
            files[key] = await _read_limited(value, key, settings.max_upload_bytes)
    return spec, files


async def _read_limited(upload: UploadFile, key: str, limit: int) -> bytes:
    data = bytearray()
    while chunk := await upload.read(_CHUNK):
        data += chunk
        if len(data) > limit:
            raise ApiError(413, "content-too-large", f"file {key!r} is larger than the limit of {limit} bytes")
    return bytes(data)


@router.post(
    "",
    status_code=201,
    response_model=GripperVersionOut,
    summary="Register a gripper spec of either kind (CONTRACT.md, metres), with its mesh files when it has geometry",
    description="A parallel gripper of boxes or a suction cup on a cylinder tool is sent as JSON. A spec with "
    "`geometry` (finger and body meshes from CAD, or a suction tool's body mesh) is sent as multipart/form-data: "
    "field `spec` holds the JSON and each file the geometry names is a file part whose field name is that path. The "
    "spec and every file are checked before anything is stored (422 naming the field). An identical spec (with "
    "identical files) returns the existing version (200); anything else under the same name becomes the next "
    "version (201), so a changed file is a new version.",
    responses={
        200: {"description": "Existing version (identical spec and files)", "model": GripperVersionOut},
        **problems(400, 413, 422),
    },
    openapi_extra={"requestBody": _SPEC_BODY},
)
def create_gripper(
    response: Response,
    principal: WriteDep,
    session: SessionDep,
    storage: StorageDep,
    settings: SettingsDep,
    body: Annotated[tuple[Any, dict[str, bytes] | None], Depends(_spec_and_files)],
) -> dict:
    spec, files = body
    out, created = crud.create_gripper(
        session, spec, files=files, storage=storage, max_decoded_bytes=settings.max_decoded_bytes
    )
    response.status_code = 201 if created else 200
    response.headers["Location"] = out["links"]["self"]
    return out


@router.get("", response_model=GripperPage, summary="List grippers by name", responses=problems(422))
def list_grippers(
    principal: ReadDep,
    session: ReadSessionDep,
    page: PagingDep,
) -> dict:
    return crud.list_grippers(session, cursor=page.cursor, limit=page.limit)


@router.get(
    "/{name}", response_model=GripperOut, summary="A gripper, its latest spec and versions", responses=problems(404)
)
def get_gripper(name: NameParam, principal: ReadDep, session: ReadSessionDep) -> dict:
    return crud.gripper_out(session, name)


@router.get(
    "/{name}/versions/{version}",
    response_model=GripperVersionOut,
    summary="One gripper version",
    responses=problems(404),
)
def get_gripper_version(name: NameParam, version: VersionParam, principal: ReadDep, session: ReadSessionDep) -> dict:
    return crud.get_gripper_version(session, name, version)


@router.get(
    "/{name}/versions/{version}/files/{path:path}",
    summary="One mesh file of a gripper version, as uploaded",
    response_class=Response,
    responses={200: {"content": {"application/octet-stream": {}}}, **problems(304, 404)},
)
def get_gripper_file(
    request: Request,
    name: NameParam,
    version: VersionParam,
    path: Annotated[str, Path(description="the file name as the spec's geometry gives it", examples=["finger.stl"])],
    principal: ReadDep,
    session: ReadSessionDep,
    storage: StorageDep,
) -> Response:
    f = crud.get_gripper_file(session, name, version, path)
    ext = f.path.rsplit(".", 1)[-1].lower()
    return blob_response(
        request,
        storage,
        f.file_key,
        media_type=_MEDIA.get(ext, "application/octet-stream"),
        filename=f"{name}-v{version}-{f.path.rsplit('/', 1)[-1]}",
        cache_control=IMMUTABLE,
    )
