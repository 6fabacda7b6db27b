"""What the catalogue serves for each object x gripper pair, and the change sequence that fleet sync pages by.

The rule (CONTRACT.md, HTTP API): the released set of the pair if there is one; otherwise the newest set computed for
the newest object version and the newest gripper version. A withdrawn set is never served (neither as released nor as
the newest). A released set stays current after newer versions appear and is then `stale`.

`catalogue_pairs` holds the result, recomputed by `refresh` in the transaction of every change that can alter it: a
new grasp set (worker), a new object or gripper version, a release, a withdrawal. Every pair whose served state
changes gets the next number of the change sequence (`change_counter`, one row).

Why a locked counter rather than a database sequence: a sequence hands out numbers at call time, so a transaction
holding 7 can commit after one holding 8; a client that synced up to 8 would never see 7. Here the counter row stays
locked (`SELECT ... FOR UPDATE`) from the first number a transaction takes until it commits, so changes commit in
sequence order and any snapshot that shows number N shows every number below it. A reader can therefore take the
largest number it sees as its watermark. Catalogue changes are rare (seconds apart), and the lock is taken last, just
before commit, so the serialisation costs nothing measurable.

Lock order: object row, gripper row, counter. Inserting a pair or an event locks the object and gripper rows it
refers to (FOR KEY SHARE, the foreign-key check), and a new object or gripper version holds its row FOR UPDATE while
it waits for the counter; so `_hold` takes those key-share locks before the counter. A holder of the counter then
waits only for catalogue rows, which only holders touch, and (the worker's result) for a bulk parent's job row, whose
holders never wait for the counter. SQLite serialises all writers anyway.
"""

from __future__ import annotations

from dataclasses import dataclass

from sqlalchemy import func, select, tuple_, update
from sqlalchemy.orm import Session

from .models import (
    CatalogueEvent,
    CataloguePair,
    ChangeCounter,
    GraspSet,
    Gripper,
    GripperVersion,
    ObjectModel,
    ObjectVersion,
    utcnow,
)

__all__ = ["ChangeSequence", "refresh", "release", "withdraw", "PairState", "CatalogueError"]


class CatalogueError(Exception):
    """A release or withdrawal that cannot be done (the API maps `code` to a problem)."""

    def __init__(self, status: int, code: str, detail: str) -> None:
        super().__init__(detail)
        self.status, self.code, self.detail = status, code, detail


class ChangeSequence:
    """The counter row, locked for the rest of the transaction; `take()` hands out the next number."""

    def __init__(self, session: Session) -> None:
        self.session = session
        value = session.execute(
            select(ChangeCounter.value).where(ChangeCounter.id == 1).with_for_update()
        ).scalar_one_or_none()
        if value is None:  # a database created without the migration's row (never in production)
            session.add(ChangeCounter(id=1, value=0))
            session.flush()
            value = 0
        self.start = self.value = int(value)

    def take(self) -> int:
        self.value += 1
        return self.value

    def save(self) -> None:
        if self.value != self.start:
            self.session.execute(update(ChangeCounter).where(ChangeCounter.id == 1).values(value=self.value))
            self.start = self.value


@dataclass(frozen=True)
class PairState:
    object_id: int
    gripper_id: int
    current_id: int | None
    released_id: int | None
    stale: bool
    change_seq: int


def _newest_versions(session: Session, model, owner_column, owner_ids: set[int]) -> dict[int, int]:
    """owner id -> id of its highest version (object or gripper versions), one query for all owners."""
    top = (
        select(owner_column.label("owner"), func.max(model.version).label("v"))
        .where(owner_column.in_(owner_ids))
        .group_by(owner_column)
        .subquery()
    )
    rows = session.execute(
        select(owner_column, model.id).join(top, (top.c.owner == owner_column) & (top.c.v == model.version))
    )
    return {owner: vid for owner, vid in rows}


def _compute(session: Session, pairs: list[CataloguePair]) -> list[tuple[int | None, bool]]:
    """(current set id, stale) of each pair from its released set and the newest versions, in a fixed number of
    queries however many pairs (a new gripper version recomputes every pair of the gripper under the counter lock)."""
    object_ids = {p.object_id for p in pairs}
    gripper_ids = {p.gripper_id for p in pairs}
    ov = _newest_versions(session, ObjectVersion, ObjectVersion.object_id, object_ids)
    gv = _newest_versions(session, GripperVersion, GripperVersion.gripper_id, gripper_ids)
    released_ids = {p.released_id for p in pairs if p.released_id is not None}
    released = (
        {
            r.id: r
            for r in session.execute(
                select(
                    GraspSet.id, GraspSet.object_version_id, GraspSet.gripper_version_id, GraspSet.withdrawn_at
                ).where(GraspSet.id.in_(released_ids))
            )
        }
        if released_ids
        else {}
    )
    # the newest set of each pair made for the newest versions, not withdrawn
    newest: dict[tuple[int, int], int] = {}
    if ov and gv:
        top = (
            select(GraspSet.object_id, GraspSet.gripper_id, func.max(GraspSet.version).label("v"))
            .where(
                GraspSet.object_id.in_(object_ids),
                GraspSet.gripper_id.in_(gripper_ids),
                GraspSet.object_version_id.in_(set(ov.values())),
                GraspSet.gripper_version_id.in_(set(gv.values())),
                GraspSet.withdrawn_at.is_(None),
            )
            .group_by(GraspSet.object_id, GraspSet.gripper_id)
        )
        # the version filter above admits another object's newest version id only if it were this object's too,
        # which cannot be (versions belong to one object); likewise for grippers
        tops = {(o, g): v for o, g, v in session.execute(top)}
        if tops:
            rows = session.execute(
                select(GraspSet.id, GraspSet.object_id, GraspSet.gripper_id).where(
                    tuple_(GraspSet.object_id, GraspSet.gripper_id, GraspSet.version).in_(
                        [(o, g, v) for (o, g), v in tops.items()]
                    )
                )
            )
            newest = {(o, g): i for i, o, g in rows}
    out: list[tuple[int | None, bool]] = []
    for p in pairs:
        r = released.get(p.released_id) if p.released_id is not None else None
        if r is not None and r.withdrawn_at is None:
            stale = r.object_version_id != ov.get(p.object_id) or r.gripper_version_id != gv.get(p.gripper_id)
            out.append((p.released_id, stale))
            continue
        p.released_id = None  # a withdrawn set is never the released one
        out.append((newest.get((p.object_id, p.gripper_id)), False))
    return out


def _refresh_pairs(session: Session, seq: ChangeSequence, pairs: list[CataloguePair], *, force: bool = False) -> int:
    """Store each pair's current set; a pair whose served state changed (or any, with `force`, or a new pair) takes
    the next change number. Returns how many did."""
    if not pairs:
        return 0
    before = [(p.current_id, p.released_id, p.stale) for p in pairs]
    changed = 0
    now = utcnow()
    for p, old, (current, stale) in zip(pairs, before, _compute(session, pairs), strict=True):
        p.current_id, p.stale = current, stale
        if force or p.change_seq == 0 or (p.current_id, p.released_id, p.stale) != old:
            p.change_seq = seq.take()
            p.updated_at = now
            changed += 1
    return changed


def _hold(session: Session, object_id: int, gripper_id: int) -> None:
    """The object's and the gripper's rows, key-share locked before the counter (module docstring: lock order)."""
    session.execute(
        select(ObjectModel.id).where(ObjectModel.id == object_id).with_for_update(read=True, key_share=True)
    )
    session.execute(select(Gripper.id).where(Gripper.id == gripper_id).with_for_update(read=True, key_share=True))


def _pair(session: Session, seq: ChangeSequence, object_id: int, gripper_id: int) -> CataloguePair:
    pair = session.execute(
        select(CataloguePair).where(CataloguePair.object_id == object_id, CataloguePair.gripper_id == gripper_id)
    ).scalar_one_or_none()
    if pair is None:
        pair = CataloguePair(
            object_id=object_id, gripper_id=gripper_id, released_id=None, current_id=None, stale=False, change_seq=0
        )
        session.add(pair)
    return pair


def refresh(session: Session, *, object_id: int | None = None, gripper_id: int | None = None) -> int:
    """Recompute the pairs a change touched: one pair (both ids; created if new), or every pair of an object or of a
    gripper (one id). Call it last in the changing transaction: it takes the counter lock until commit. Returns how
    many pairs changed what they serve."""
    if object_id is not None and gripper_id is not None:
        _hold(session, object_id, gripper_id)
        seq = ChangeSequence(session)
        pairs = [_pair(session, seq, object_id, gripper_id)]
    else:
        q = select(CataloguePair)
        if object_id is not None:
            q = q.where(CataloguePair.object_id == object_id)
        elif gripper_id is not None:
            q = q.where(CataloguePair.gripper_id == gripper_id)
        else:
            raise ValueError("refresh needs an object id, a gripper id or both")
        # existing pairs only: their updates change no foreign key, so no further row locks
        seq = ChangeSequence(session)
        pairs = list(session.execute(q.order_by(CataloguePair.object_id, CataloguePair.gripper_id)).scalars())
    changed = _refresh_pairs(session, seq, pairs)
    seq.save()
    session.flush()
    return changed


def _state(pair: CataloguePair) -> PairState:
    return PairState(pair.object_id, pair.gripper_id, pair.current_id, pair.released_id, pair.stale, pair.change_seq)


def _locked_set(session: Session, grasp_set_id: int) -> tuple[GraspSet, ChangeSequence]:
    gs = session.get(GraspSet, grasp_set_id)
    if gs is None:
        raise CatalogueError(404, "not-found", f"no grasp set {grasp_set_id}")
    _hold(session, gs.object_id, gs.gripper_id)
    # then the counter: every catalogue change is serialised behind it, so what is read below is the latest
    seq = ChangeSequence(session)
    session.refresh(gs)
    return gs, seq


def release(session: Session, grasp_set_id: int, by: str) -> tuple[PairState, CatalogueEvent | None]:
    """Make the set the released one of its pair (a withdrawn set is reinstated). Releasing the released set again
    changes nothing and records nothing (event None)."""
    gs, seq = _locked_set(session, grasp_set_id)
    pair = _pair(session, seq, gs.object_id, gs.gripper_id)
    if pair.released_id == gs.id and gs.withdrawn_at is None:
        return _state(pair), None
    event = CatalogueEvent(
        object_id=gs.object_id,
        gripper_id=gs.gripper_id,
        grasp_set_id=gs.id,
        action="release",
        at=utcnow(),
        by=by,
        replaced_id=pair.released_id,
    )
    session.add(event)
    gs.withdrawn_at = None
    pair.released_id = gs.id
    _refresh_pairs(session, seq, [pair], force=True)
    seq.save()
    session.flush()
    return _state(pair), event


def withdraw(session: Session, grasp_set_id: int, by: str) -> tuple[PairState, CatalogueEvent | None]:
    """The set is never served again by the catalogue (neither as released nor as the newest); the pair falls back
    to the rule without it. Withdrawing a withdrawn set changes nothing (event None)."""
    gs, seq = _locked_set(session, grasp_set_id)
    pair = _pair(session, seq, gs.object_id, gs.gripper_id)
    if gs.withdrawn_at is not None:
        return _state(pair), None
    at = utcnow()
    event = CatalogueEvent(
        object_id=gs.object_id, gripper_id=gs.gripper_id, grasp_set_id=gs.id, action="withdraw", at=at, by=by
    )
    session.add(event)
    gs.withdrawn_at = at
    if pair.released_id == gs.id:
        pair.released_id = None
    _refresh_pairs(session, seq, [pair])
    seq.save()
    session.flush()
    return _state(pair), event
