"""Catalogue releases and withdrawals (issue 15): the "current" rule, its headers, history, scopes, fleet sync by
change number, and two concurrent catalogue changes on PostgreSQL."""

from __future__ import annotations

import threading
import time

import pytest
from services_conftest import box_stl, slug, store_grasp_set_row
from sqlalchemy import select, text

from services.common import catalogue
from services.common.models import GraspSet, Gripper, GripperVersion, ObjectModel, ObjectVersion

pytestmark = pytest.mark.integration


@pytest.fixture(params=["pg_service", "sqlite_service"])
def svc(request):  # type: ignore[no-untyped-def]
    """PostgreSQL + Redis, and the embedded default (SQLite, in-process worker)."""
    return request.getfixturevalue(request.param)


def wait_blocked_by(watch, pid1: int, pid2: list[int], failure) -> None:  # type: ignore[no-untyped-def]
    """Wait until the backend whose pid the other thread appends to `pid2` once it started waits for a lock that
    backend `pid1` holds (pg_blocking_pids: pg_stat_activity's query text is not reliable for prepared statements);
    fail with `failure()` after 120 s: a condition awaited, not a speed, so generous for a loaded machine."""
    blocked = text("SELECT :p1 = ANY(pg_blocking_pids(:p2))")
    deadline = time.monotonic() + 120
    while not (pid2 and watch.execute(blocked, {"p1": pid1, "p2": pid2[0]}).scalar_one()):
        if time.monotonic() >= deadline:
            raise AssertionError(failure())
        threading.Event().wait(0.01)


def add_set(svc, obj: str, grip: str, *, ov: int | None = None, gv: int | None = None) -> int:
    """A grasp set stored as the worker stores one (rows, export blob, catalogue refresh), for the given object and
    gripper versions (default: the newest)."""
    state = svc.app.state
    with state.db.session() as s:
        # the object row numbers its sets (the worker's lock)
        o = s.execute(select(ObjectModel).where(ObjectModel.name == obj).with_for_update()).scalar_one()
        g = s.execute(select(Gripper).where(Gripper.name == grip)).scalar_one()
        ovq = select(ObjectVersion).where(ObjectVersion.object_id == o.id)
        gvq = select(GripperVersion).where(GripperVersion.gripper_id == g.id)
        ovq = ovq.where(ObjectVersion.version == ov) if ov else ovq.order_by(ObjectVersion.version.desc())
        gvq = gvq.where(GripperVersion.version == gv) if gv else gvq.order_by(GripperVersion.version.desc())
        o_v = s.execute(ovq.limit(1)).scalar_one()
        g_v = s.execute(gvq.limit(1)).scalar_one()
        n = (
            s.execute(
                select(GraspSet.version)
                .where(GraspSet.object_id == o.id, GraspSet.gripper_id == g.id)
                .order_by(GraspSet.version.desc())
                .limit(1)
            ).scalar_one_or_none()
            or 0
        ) + 1
        export = {"format": "graspgen.grasp_set/1", "params": {"points": 1000 + n, "seed": n}}
        gs_id = store_grasp_set_row(s, state.storage, o_v, g_v, n, export)
        catalogue.refresh(s, object_id=o.id, gripper_id=g.id)
        return gs_id


def pair(svc, grip: str = "", obj: str = "") -> tuple[str, str]:
    """An object and a gripper registered through the API (new names unless given)."""
    obj = obj or slug("rel")
    grip = grip or slug("g")
    assert svc.gripper(grip).status_code in (200, 201)
    assert svc.upload(obj, box_stl()).status_code in (200, 201)
    return obj, grip


def objects_with_a_set(svc, grip: str, prefix: str, n: int) -> dict[str, int]:
    """`n` new objects for gripper `grip`, each with one grasp set: name -> set id, by name."""
    ids = {}
    for name in sorted(slug(prefix) for _ in range(n)):
        pair(svc, grip, name)
        ids[name] = add_set(svc, name, grip)
    return ids


def served(svc, obj: str, grip: str) -> tuple[int, int | None, str | None, str | None]:
    r = svc.get(f"/v1/catalogue/{obj}/{grip}")
    h = r.headers
    sid = int(h["graspgen-set-id"]) if "graspgen-set-id" in h else None
    return r.status_code, sid, h.get("graspgen-released"), h.get("graspgen-stale")


def test_release_pins_a_set_until_withdrawn_and_history_records_who_and_when(svc):
    obj, grip = pair(svc)
    a = add_set(svc, obj, grip)
    b = add_set(svc, obj, grip)
    assert served(svc, obj, grip) == (200, b, "false", "false")  # the newest, nothing released

    r = svc.post(f"/v1/grasp-sets/{a}/release", who="writer")
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["changed"] and body["current"] == a and body["released"] == a and body["event"]["by"] == "writer"
    got = svc.get(f"/v1/catalogue/{obj}/{grip}")
    assert got.headers["content-location"] == f"/v1/grasp-sets/{a}" and got.json()["params"]["seed"] == 1
    assert served(svc, obj, grip) == (200, a, "true", "false")

    # a newer object version: the released set stays current, flagged stale, even once a set exists for it
    assert svc.upload(obj, box_stl((41.0, 30.0, 20.0))).json()["version"] == 2
    assert served(svc, obj, grip) == (200, a, "true", "true")
    c = add_set(svc, obj, grip)
    assert served(svc, obj, grip) == (200, a, "true", "true")

    r = svc.post(f"/v1/grasp-sets/{a}/withdraw", who="writer2")
    assert r.status_code == 200 and r.json()["released"] is None and r.json()["current"] == c
    assert served(svc, obj, grip) == (200, c, "false", "false")  # the rule without a release
    gone = svc.get(f"/v1/catalogue/{obj}/{grip}?version=1")
    assert gone.status_code == 404 and gone.json()["code"] == "withdrawn"
    assert svc.get(f"/v1/grasp-sets/{a}").status_code == 200  # the archive keeps it
    listed = {i["id"]: i for i in svc.get(f"/v1/grasp-sets?object={obj}&gripper={grip}").json()["items"]}
    assert listed[a]["withdrawn_at"] is not None and listed[b]["withdrawn_at"] is None
    again = svc.post(f"/v1/grasp-sets/{a}/withdraw")
    assert again.status_code == 200 and again.json()["changed"] is False

    # a set for the old object version can be released on purpose: it is served, stale
    assert svc.post(f"/v1/grasp-sets/{b}/release").json()["event"]["replaced"] is None
    assert served(svc, obj, grip) == (200, b, "true", "true")
    v2 = svc.get(f"/v1/catalogue/{obj}/{grip}?version=2")
    assert v2.headers["graspgen-released"] == "true" and v2.headers["graspgen-stale"] == "true"
    v3 = svc.get(f"/v1/catalogue/{obj}/{grip}?version=3")
    assert (v3.headers["graspgen-released"], v3.headers["graspgen-stale"]) == ("false", "false")
    assert svc.post(f"/v1/grasp-sets/{c}/release", who="admin").json()["event"]["replaced"] == b
    assert served(svc, obj, grip) == (200, c, "true", "false")
    assert svc.post(f"/v1/grasp-sets/{c}/release").json()["changed"] is False

    hist = svc.get(f"/v1/catalogue/{obj}/{grip}/history?limit=2")
    assert hist.status_code == 200
    first = hist.json()
    rest = svc.get(first["links"]["next"]).json()
    events = [(e["grasp_set"], e["action"], e["by"]) for e in first["items"] + rest["items"]]
    assert events == [
        (c, "release", "admin"),
        (b, "release", "writer"),
        (a, "withdraw", "writer2"),
        (a, "release", "writer"),
    ]
    ats = [e["at"] for e in first["items"] + rest["items"]]
    assert ats == sorted(ats, reverse=True)
    assert rest["next_cursor"] is None


def test_without_a_release_only_a_set_for_the_newest_object_and_gripper_versions_is_served(svc):
    obj, grip = pair(svc)
    old = add_set(svc, obj, grip)
    assert served(svc, obj, grip)[:2] == (200, old)
    assert svc.upload(obj, box_stl((40.0, 31.0, 20.0))).status_code == 201
    miss = svc.get(f"/v1/catalogue/{obj}/{grip}")
    assert miss.status_code == 404 and miss.headers["content-type"] == "application/problem+json"
    assert "graspgen-set-id" not in miss.headers
    mid = add_set(svc, obj, grip)  # newest object version, gripper version 1
    assert served(svc, obj, grip)[:2] == (200, mid)
    assert svc.gripper(grip, stroke=0.09).json()["version"] == 2  # the fingers changed
    assert served(svc, obj, grip)[0] == 404
    add_set(svc, obj, grip, ov=1)  # newest gripper, old object version: never current
    assert served(svc, obj, grip)[0] == 404
    new = add_set(svc, obj, grip)
    assert served(svc, obj, grip) == (200, new, "false", "false")
    # a withdrawn set is not served as the newest either; the older ones do not qualify
    assert svc.post(f"/v1/grasp-sets/{new}/withdraw").status_code == 200
    assert served(svc, obj, grip)[0] == 404
    assert svc.post(f"/v1/grasp-sets/{new}/release").status_code == 200  # reinstated by a release
    assert served(svc, obj, grip) == (200, new, "true", "false")


def test_release_and_withdraw_need_write_scope_and_an_existing_set(svc):
    obj, grip = pair(svc)
    gs = add_set(svc, obj, grip)
    for action in ("release", "withdraw"):
        url = f"/v1/grasp-sets/{gs}/{action}"
        anon = svc.client.post(url)
        assert anon.status_code == 401 and anon.headers["content-type"] == "application/problem+json"
        ro = svc.post(url, who="reader")
        assert ro.status_code == 403 and ro.json()["code"] == "forbidden"
        missing = svc.post(f"/v1/grasp-sets/{2**31 - 2}/{action}")
        assert missing.status_code == 404 and missing.json()["code"] == "not-found"
        assert svc.post(f"/v1/grasp-sets/{2**31}/{action}").status_code == 422
    assert svc.get(f"/v1/catalogue/{obj}/{grip}/history").json()["items"] == []  # nothing was recorded
    assert svc.client.get(f"/v1/catalogue/{obj}/{grip}/history").status_code == 401
    assert svc.get(f"/v1/catalogue/no-such-object/{grip}/history").status_code == 404
    assert svc.get(f"/v1/catalogue/{obj}/{grip}/history?cursor=zz").status_code == 422


def sync(svc, grip: str, since: int | None = None, limit: int = 100) -> tuple[list[dict], int]:
    """Every page of one fleet sync; returns (items, next_since of the last page)."""
    url = f"/v1/catalogue?gripper={grip}&limit={limit}" + (f"&since={since}" if since is not None else "")
    items: list[dict] = []
    for _ in range(100):
        r = svc.get(url)
        assert r.status_code == 200, r.text
        items += r.json()["items"]
        if r.json()["next_cursor"] is None:
            return items, r.json()["next_since"]
        url = r.json()["links"]["next"]
    raise AssertionError("pagination did not end")


def test_fleet_sync_by_change_number_reports_releases_withdrawals_and_dropped_pairs(svc):
    grip = slug("fleet")
    ids = objects_with_a_set(svc, grip, "f", 4)
    names = list(ids)
    full, mark = sync(svc, grip, limit=3)
    assert [i["object"] for i in full] == names and all(i["withdrawn"] is False for i in full)
    assert {i["object"]: i["id"] for i in full} == ids
    assert mark == max(i["change_seq"] for i in full)

    nothing, mark2 = sync(svc, grip, since=mark)
    assert nothing == [] and mark2 == mark
    first = svc.get(f"/v1/catalogue?gripper={grip}&since={mark}")
    assert first.status_code == 200
    cached = svc.get(f"/v1/catalogue?gripper={grip}&since={mark}", headers={"If-None-Match": first.headers["etag"]})
    assert cached.status_code == 304

    a, b, c, d = names
    newer = add_set(svc, a, grip)  # a new set: a's current changes
    assert svc.post(f"/v1/grasp-sets/{ids[b]}/release").status_code == 200  # released flag changes
    assert svc.post(f"/v1/grasp-sets/{ids[c]}/withdraw").status_code == 200  # c serves nothing now
    assert svc.upload(d, box_stl((40.0, 30.0, 21.0))).status_code == 201  # d's only set is outdated
    changed = svc.get(f"/v1/catalogue?gripper={grip}&since={mark}", headers={"If-None-Match": first.headers["etag"]})
    assert changed.status_code == 200

    delta, mark3 = sync(svc, grip, since=mark, limit=1)  # one pair per page, in change order
    assert [i["object"] for i in delta] == [a, b, c, d]
    assert [i["change_seq"] for i in delta] == sorted(i["change_seq"] for i in delta) and mark3 > mark
    assert delta[0]["id"] == newer and delta[0]["withdrawn"] is False
    assert delta[1]["id"] == ids[b] and delta[1]["released"] is True
    assert delta[2] == {
        "id": None,
        "object": c,
        "gripper": grip,
        "released": False,
        "stale": False,
        "withdrawn": True,
        "change_seq": delta[2]["change_seq"],
        "links": {"catalogue": f"/v1/catalogue/{c}/{grip}"},
    }
    assert delta[3]["object"] == d and delta[3]["withdrawn"] is True
    assert sync(svc, grip, since=mark3) == ([], mark3)

    # the full listing leaves out pairs that serve nothing; a robot applying the delta to its copy gets the same
    robot = {i["object"]: i["id"] for i in full}
    for i in delta:
        if i["withdrawn"]:
            robot.pop(i["object"], None)
        else:
            robot[i["object"]] = i["id"]
    assert robot == {i["object"]: i["id"] for i in sync(svc, grip)[0]} == {a: newer, b: ids[b]}
    bad = svc.get(f"/v1/catalogue?gripper={grip}&since=-1")
    assert bad.status_code == 422
    from services.api.pagination import encode_cursor

    for forged in ([2**63, 0], [0, 2**70], ["x", 0]):
        r = svc.get(f"/v1/catalogue?gripper={grip}&since=0&cursor={encode_cursor(forged)}")
        assert r.status_code == 422 and r.json()["code"] == "invalid-cursor", (forged, r.text)


def test_concurrent_catalogue_changes_commit_in_change_order(pg_service):
    """Transaction 1 takes a change number and stays open; transaction 2 (another pair) must wait for it before it
    can take the next one, so no reader can see number n+1 without n. The wait is observed (transaction 1's
    backend blocks transaction 2's), not timed."""
    svc = pg_service
    grip = slug("conc")
    one, two = slug("c1"), slug("c2")
    pair(svc, grip, one)
    pair(svc, grip, two)
    s1_id = add_set(svc, one, grip)
    s2_id = add_set(svc, two, grip)
    _, mark = sync(svc, grip)
    db = svc.app.state.db
    s1 = db.sessions()
    s1.begin()
    state1, _ = catalogue.release(s1, s1_id, "t1")
    pid1 = s1.execute(text("SELECT pg_backend_pid()")).scalar_one()
    pid2: list[int] = []
    result2: list = []

    def second() -> None:
        with db.sessions() as s2, s2.begin():
            pid2.append(s2.execute(text("SELECT pg_backend_pid()")).scalar_one())
            result2.append(catalogue.release(s2, s2_id, "t2")[0])

    t = threading.Thread(target=second)
    t.start()
    try:
        with db.engine.connect() as watch:
            wait_blocked_by(watch, pid1, pid2, lambda: "transaction 2 never waited for the change counter")
        # while 1 is open, a sync sees neither change and its watermark stays below both
        assert sync(svc, grip, since=mark) == ([], mark)
        assert not result2
    finally:
        s1.commit()
        s1.close()
        t.join(30)
    assert result2 and result2[0].change_seq == state1.change_seq + 1
    delta, _ = sync(svc, grip, since=mark)
    assert [(i["object"], i["released"]) for i in delta] == [(one, True), (two, True)]


def test_a_release_waits_for_a_locked_object_row_before_it_takes_the_counter(pg_service):
    """Lock order object, gripper, counter: an upload of a new object version holds the object row FOR UPDATE and then
    takes the counter; a release of a set of that object must wait for the object row before it takes the counter,
    or the two would deadlock (PostgreSQL would abort one of them)."""
    svc = pg_service
    obj, grip = pair(svc)
    gs = add_set(svc, obj, grip)
    db = svc.app.state.db
    s1 = db.sessions()
    s1.begin()
    s1.execute(select(ObjectModel.id).where(ObjectModel.name == obj).with_for_update())
    pid1 = s1.execute(text("SELECT pg_backend_pid()")).scalar_one()
    result: list = []
    pid2: list[int] = []

    def release() -> None:  # what POST /v1/grasp-sets/{id}/release runs
        from services.api.crud.grasp_sets import release as crud_release

        try:
            with db.sessions() as s2:
                pid2.append(s2.execute(text("SELECT pg_backend_pid()")).scalar_one())
                result.append(crud_release(s2, gs, "writer"))
        except BaseException as exc:  # reported below
            result.append(exc)

    t = threading.Thread(target=release)
    t.start()
    try:
        with db.engine.connect() as watch:
            # blocked by transaction 1 (the object row)
            wait_blocked_by(watch, pid1, pid2, lambda: f"the release never waited for the object row: {result}")
            held = watch.execute(
                text(
                    "SELECT count(*) FROM pg_locks l JOIN pg_class c ON c.oid = l.relation "
                    "WHERE l.pid = :p AND c.relname = 'change_counter'"
                ),
                {"p": pid2[0]},
            ).scalar_one()
            assert held == 0  # it waits without having touched the counter
        seq = catalogue.ChangeSequence(s1)  # what the upload does next: the counter is free
        seq.take()
        seq.save()
        s1.commit()
    finally:
        s1.close()
        t.join(30)
    assert result and result[0]["changed"] and result[0]["released"] == gs
    assert served(svc, obj, grip) == (200, gs, "true", "false")


def test_a_robot_syncing_during_concurrent_changes_ends_with_the_catalogue(svc):
    """Three writers release, withdraw and add sets at random while a robot syncs by `since` in a loop; once they
    stop and the robot syncs once more, its copy equals the full listing (no change was missed), and its watermark
    never went back."""
    import random

    grip = slug("race")
    names = [slug("r") for _ in range(5)]
    sets: dict[str, list[int]] = {}
    for n in names:
        pair(svc, grip, n)
        sets[n] = [add_set(svc, n, grip), add_set(svc, n, grip)]
    full, mark = sync(svc, grip)
    robot = {i["object"]: i["id"] for i in full}
    db = svc.app.state.db
    errors: list[BaseException] = []

    def writer(seed: int) -> None:
        rng = random.Random(seed)
        try:
            for _ in range(15):
                obj = rng.choice(names)
                action = rng.choice(("release", "withdraw", "release", "add"))
                if action == "add":
                    sets[obj].append(add_set(svc, obj, grip))
                    continue
                with db.sessions() as s, s.begin():
                    do = catalogue.release if action == "release" else catalogue.withdraw
                    do(s, rng.choice(sets[obj]), f"w{seed}")
        except BaseException as exc:  # reported below
            errors.append(exc)

    threads = [threading.Thread(target=writer, args=(i,)) for i in range(3)]
    for t in threads:
        t.start()

    def apply(items: list[dict]) -> None:
        for i in items:
            if i["withdrawn"]:
                robot.pop(i["object"], None)
            else:
                robot[i["object"]] = i["id"]

    marks = [mark]
    while any(t.is_alive() for t in threads):
        items, mark = sync(svc, grip, since=mark, limit=2)
        apply(items)
        marks.append(mark)
    for t in threads:
        t.join()
    assert not errors, errors
    items, mark = sync(svc, grip, since=mark)
    apply(items)
    marks.append(mark)
    assert marks == sorted(marks) and len(marks) > 2
    assert robot == {i["object"]: i["id"] for i in sync(svc, grip)[0]}


def test_a_new_gripper_version_recomputes_every_pair_of_the_gripper(svc):
    grip = slug("gv")
    ids = objects_with_a_set(svc, grip, "p", 3)
    names = list(ids)
    one, two, three = names
    assert svc.post(f"/v1/grasp-sets/{ids[one]}/release").status_code == 200
    _, mark = sync(svc, grip)
    assert svc.gripper(grip, finger_depth=0.035).json()["version"] == 2  # new fingers
    assert served(svc, one, grip) == (200, ids[one], "true", "true")  # the release holds, now stale
    assert served(svc, two, grip)[0] == 404 and served(svc, three, grip)[0] == 404
    delta, mark2 = sync(svc, grip, since=mark)
    assert {i["object"]: (i["id"], i["stale"], i["withdrawn"]) for i in delta} == {
        one: (ids[one], True, False),
        two: (None, False, True),
        three: (None, False, True),
    }
    fresh = add_set(svc, two, grip)
    assert served(svc, two, grip) == (200, fresh, "false", "false")
    assert [(i["object"], i["id"]) for i in sync(svc, grip, since=mark2)[0]] == [(two, fresh)]
