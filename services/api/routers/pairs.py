from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from ..crud import pairs as crud
from ..deps import PagingDep, ReadDep, ReadSessionDep
from ..schemas import SLUG, PairPage
from . import problems

router = APIRouter(prefix="/v1", tags=["catalogue"])


@router.get(
    "/pairs",
    response_model=PairPage,
    summary="Every object x gripper pair with the set it serves, released and stale flags and its last change",
    description="Pairs that have, or had, a grasp set, by object name then gripper name, paginated by cursor; across "
    "all grippers (fleet sync of one gripper is `GET /v1/catalogue`). `object_contains` keeps objects whose name "
    "contains it, `gripper` one gripper, `released` and `stale` the pairs whose current set is (not) so. `total` "
    "counts every matching pair.",
    responses=problems(422),
)
def list_pairs(
    principal: ReadDep,
    session: ReadSessionDep,
    page: PagingDep,
    object_contains: Annotated[
        str | None, Query(max_length=63, pattern=r"^[a-z0-9._-]*$", description="part of an object name")
    ] = None,
    gripper: Annotated[str | None, Query(pattern=SLUG)] = None,
    released: bool | None = None,
    stale: bool | None = None,
) -> dict:
    return crud.list_pairs(
        session,
        object_contains=object_contains,
        gripper=gripper,
        released=released,
        stale=stale,
        cursor=page.cursor,
        limit=page.limit,
    )
