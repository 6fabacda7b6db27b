from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, File, Form, Path, Request, Response, UploadFile

from ..crud import objects as crud
from ..deps import PagingDep, ReadDep, ReadSessionDep, SessionDep, SettingsDep, StorageDep, WriteDep
from ..http import IMMUTABLE, blob_response
from ..schemas import ID_MAX, SLUG, ObjectOut, ObjectPage, ObjectVersionOut
from . import problems

router = APIRouter(prefix="/v1/objects", tags=["objects"])

NameParam = Annotated[str, Path(pattern=SLUG, examples=["ring-screw"])]
VersionParam = Annotated[int, Path(ge=1, le=ID_MAX, examples=[3])]

_MEDIA = {"stl": "model/stl", "obj": "model/obj", "glb": "model/gltf-binary", "ply": "application/x-ply"}


@router.post(
    "",
    status_code=201,
    response_model=ObjectVersionOut,
    summary="Upload a part (mesh or point cloud) under a name",
    description="Multipart upload. The same bytes with the same units under the same name return the existing "
    "version with 200; anything else becomes the next version (201). The file is checked with graspgen's "
    "loader (units, size plausibility, geometry) before it is stored. `mass_kg` is stored on the version; the same "
    "bytes with a different mass are a 409.",
    responses={
        200: {"description": "Existing version (identical upload)", "model": ObjectVersionOut},
        **problems(409, 413, 422),
    },
)
def upload_object(
    response: Response,
    principal: WriteDep,
    session: SessionDep,
    storage: StorageDep,
    settings: SettingsDep,
    file: Annotated[UploadFile, File(description="STL, OBJ, PLY, OFF, GLB mesh or PLY/NPZ point cloud")],
    name: Annotated[str, Form(description="slug", examples=["ring-screw"])],
    units: Annotated[str, Form(description="mm, cm, m or in", examples=["mm"])],
    format: Annotated[str | None, Form(description="file type; default: the file name's extension")] = None,
    mass_kg: Annotated[
        float | None,
        Form(description="the part's mass in kg (> 0): jobs without mass_kg or density use it for criterion (e)"),
    ] = None,
) -> dict:
    out, created = crud.upload_object(
        session,
        storage,
        settings,
        name=name,
        units=units,
        fmt=format,
        filename=file.filename,
        stream=file.file,
        mass_kg=mass_kg,
    )
    response.status_code = 201 if created else 200
    response.headers["Location"] = out["links"]["self"]
    return out


@router.get("", response_model=ObjectPage, summary="List objects by name", responses=problems(422))
def list_objects(
    principal: ReadDep,
    session: ReadSessionDep,
    page: PagingDep,
) -> dict:
    return crud.list_objects(session, cursor=page.cursor, limit=page.limit)


@router.get("/{name}", response_model=ObjectOut, summary="An object and all its versions", responses=problems(404))
def get_object(name: NameParam, principal: ReadDep, session: ReadSessionDep) -> dict:
    return crud.get_object(session, name)


@router.get(
    "/{name}/versions/{version}",
    response_model=ObjectVersionOut,
    summary="One object version",
    responses=problems(404),
)
def get_object_version(name: NameParam, version: VersionParam, principal: ReadDep, session: ReadSessionDep) -> dict:
    return crud.version_out(name, crud.get_version(session, name, version))


@router.get(
    "/{name}/versions/{version}/file",
    summary="The uploaded file of one object version, as uploaded",
    response_class=Response,
    responses={200: {"content": {"application/octet-stream": {}}}, **problems(304, 404)},
)
def get_object_file(
    request: Request,
    name: NameParam,
    version: VersionParam,
    principal: ReadDep,
    session: ReadSessionDep,
    storage: StorageDep,
) -> Response:
    v = crud.get_version(session, name, version)
    return blob_response(
        request,
        storage,
        v.file_key,
        media_type=_MEDIA.get(v.format, "application/octet-stream"),
        filename=f"{name}-v{version}.{v.format}",
        cache_control=IMMUTABLE,
    )
