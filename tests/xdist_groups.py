"""`--dist loadgroup` (scripts/test.sh) keeps each `xdist_group` on one worker under pytest >= 9.2 too.

pytest-xdist 3.8 tells the controller an item's group by appending `@group` to the item's node id on the worker, which
it does by assigning `item._nodeid`. pytest 9.2 keeps node ids as structured `NodeId`s (`item._id`) and no longer reads
`_nodeid`, so the suffix is lost and every test becomes a group of its own (pytest-dev/pytest-xdist#1386): the tests
of one module that share a module fixture in order (tests/ui, tests/reliability) were spread over both workers. This
hook, run after xdist's, writes the suffix where pytest reads it when xdist's own assignment did not take.
"""

from __future__ import annotations

import pytest


def group_names(item: pytest.Item) -> list[str]:
    """The item's xdist_group names, sorted, as xdist joins them."""
    names = {str(m.args[0] if m.args else m.kwargs.get("name", "default")) for m in item.iter_markers("xdist_group")}
    return sorted(names)


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if not getattr(config.option, "loadgroup", False):  # set on xdist workers under --dist loadgroup only
        return
    for item in items:
        names = group_names(item)
        suffix = "@" + "_".join(names)
        if not names or item.nodeid.endswith(suffix):
            continue
        structured = getattr(item, "_id", None)
        if structured is None or not hasattr(type(structured), "parse"):
            raise RuntimeError(f"cannot put {item.nodeid} in xdist group {suffix[1:]}: unknown pytest node id type")
        item._id = type(structured).parse(item.nodeid + suffix)
