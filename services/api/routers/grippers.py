from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Body, Path, Response
from pydantic import WithJsonSchema

from ..crud import grippers as crud
from ..deps import PagingDep, ReadDep, ReadSessionDep, SessionDep, WriteDep
from ..schemas import GRIPPER_SPEC_EXAMPLE, ID_MAX, SLUG, GripperOut, GripperPage, GripperVersionOut
from . import problems

router = APIRouter(prefix="/v1/grippers", tags=["grippers"])

NameParam = Annotated[str, Path(pattern=SLUG, examples=["pgn-80"])]


@router.post(
    "",
    status_code=201,
    response_model=GripperVersionOut,
    summary="Register a gripper spec (CONTRACT.md, metres)",
    description="An identical spec returns the existing version (200); a changed spec under the same name becomes "
    "the next version (201).",
    responses={
        200: {"description": "Existing version (identical spec)", "model": GripperVersionOut},
        **problems(413, 422),
    },
)
def create_gripper(
    response: Response,
    principal: WriteDep,
    session: SessionDep,
    spec: Annotated[
        dict[str, Any],
        Body(examples=[GRIPPER_SPEC_EXAMPLE]),
        # documented as the typed spec; graspgen's GripperSpec.from_dict validates it (one source of messages)
        WithJsonSchema({"allOf": [{"$ref": "#/components/schemas/GripperSpec"}]}),
    ],
) -> dict:
    out, created = crud.create_gripper(session, spec)
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
def get_gripper_version(
    name: NameParam, version: Annotated[int, Path(ge=1, le=ID_MAX)], principal: ReadDep, session: ReadSessionDep
) -> dict:
    return crud.get_gripper_version(session, name, version)
