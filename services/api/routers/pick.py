from __future__ import annotations

from fastapi import APIRouter, Request, Response

from ..contract_schemas import PickRequest, PickResponse
from ..crud import pick as crud
from ..crud.grasp_sets import dumps
from ..deps import ReadDep
from . import problems

router = APIRouter(prefix="/v1", tags=["pick"])


@router.post(
    "/pick",
    response_model=PickResponse,
    summary="World-frame grasps of a grasp set that fit the scene (approach cone, bin planes), best first",
    description="Every candidate of the set (the NPZ, not only the exported representatives) at every free roll is "
    "considered; see docs/API.md for frames and the roll convention. An empty `grasps` comes with `reason`, how many "
    "pairs the cone and the planes removed. A set without stored candidates is a 404 `no-candidates`.",
    responses=problems(404, 413, 422),
)
def pick(body: PickRequest, request: Request, principal: ReadDep) -> Response:
    # no database session is held while filtering: crud.run_pick opens and closes its own for the lookup
    out = crud.run_pick(request.app.state, body.model_dump())
    return Response(dumps(out), media_type="application/json")
