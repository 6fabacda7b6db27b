"""scripts/test.sh runs the suite with `-n 2 --dist loadgroup`: every test of one `xdist_group` goes to one worker,
which the modules with one expensive stack per module (a served browser session, a worker pool) rely on. pytest-xdist
marks a grouped test by appending `@group` to its node id; when pytest ignores that (pytest 9.2 with xdist 3.8), the
groups are silently split and those modules' tests run on two half-prepared stacks. This test fails then."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.xdist_group("xdist-group-check")


def test_a_grouped_test_carries_its_group_under_loadgroup(request: pytest.FixtureRequest) -> None:
    if not getattr(request.config.option, "loadgroup", False):  # set in each worker by pytest-xdist
        pytest.skip("only meaningful under pytest -n N --dist loadgroup (scripts/test.sh)")
    assert request.node.nodeid.endswith("@xdist-group-check"), request.node.nodeid
