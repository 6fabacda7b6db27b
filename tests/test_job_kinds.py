"""The registry of job kinds (services/jobkinds, issue 17): every kind is complete, the body of `POST /v1/jobs` is the
discriminated union of exactly the kinds that run, and no module outside the registry names a kind by a string
literal (so a new kind is one module and one line in the registry)."""

from __future__ import annotations

import ast
import typing
from pathlib import Path

import pytest
from pydantic import BaseModel, ValidationError

from services.common.models import Job
from services.jobkinds import (
    CONTAINER_KINDS,
    DEFAULT_KIND,
    KINDS,
    RUNNABLE,
    ContainerKind,
    JobKind,
    JobRequest,
    is_container,
)

ROOT = Path(__file__).resolve().parents[1]
REGISTRY = ROOT / "services" / "jobkinds"


def test_every_kind_is_complete():
    column = Job.__table__.c.kind.type.length
    assert set(KINDS) == set(RUNNABLE) | set(CONTAINER_KINDS) and not set(RUNNABLE) & set(CONTAINER_KINDS)
    for name, kind in KINDS.items():
        assert kind.name == name and len(name) <= column, name
        if isinstance(kind, ContainerKind):
            assert is_container(name)
            assert RUNNABLE[kind.item.name] is kind.item, name  # its items are of a registered kind that runs
            continue
        assert isinstance(kind, JobKind) and not is_container(name)
        assert issubclass(kind.request, BaseModel) and callable(kind.resolve) and callable(kind.run), name
        assert kind.request.model_fields["kind"].annotation == typing.Literal[name], name
        assert kind.request.model_config.get("extra") == "forbid", name
        assert kind.stage_weights and all(w > 0 for w in kind.stage_weights.values()), name
        for validate in (True, False):
            weights = kind.progress_weights(validate=validate)
            assert abs(sum(weights.values()) - 1) < 1e-9 and ("validate" in weights) == validate, name
            assert list(weights) == [s for s in kind.stage_weights if s in weights]  # the order the stages run
    assert DEFAULT_KIND in RUNNABLE


def test_the_request_body_is_the_union_of_the_kinds_that_run():
    root = JobRequest.model_fields["root"]
    assert root.discriminator == "kind"
    assert set(typing.get_args(root.annotation)) == {k.request for k in RUNNABLE.values()}
    for name in RUNNABLE:
        with pytest.raises(ValidationError) as err:
            JobRequest.model_validate({"kind": name, "no-such-field": 1})
        # the tag chose the kind's own model, whose validation refused the body
        assert {e["loc"][0] for e in err.value.errors()} == {name}, err.value.errors()
    for name in (*CONTAINER_KINDS, "no-such-kind", None):
        with pytest.raises(ValidationError) as err:
            JobRequest.model_validate({"kind": name, "object": "a", "gripper": "b"})
        assert [e["type"] for e in err.value.errors()] == ["union_tag_invalid"], name


def test_a_body_without_kind_is_of_the_default_kind():
    body = JobRequest.model_validate({"object": "ring-screw", "gripper": "pgn-80"})
    assert isinstance(body.root, RUNNABLE[DEFAULT_KIND].request) and body.root.kind == DEFAULT_KIND
    # the stored request names the kind, as it did when `kind` was a field with a default
    assert body.model_dump(exclude_none=True) == {"kind": DEFAULT_KIND, "object": "ring-screw", "gripper": "pgn-80"}


def test_the_examples_of_every_kind_are_valid_bodies():
    examples = JobRequest.model_config["json_schema_extra"]["examples"]
    assert examples
    for kind in RUNNABLE.values():
        own = kind.request.model_config["json_schema_extra"]["examples"]
        assert own and all(ex in examples for ex in own)
        for ex in own:
            assert type(JobRequest.model_validate(ex).root) is kind.request, ex


# -- no kind named outside the registry -------------------------------------------------------------------------------
def _is_kind(node: ast.AST) -> bool:
    """`kind`, `x.kind` or `x["kind"]`."""
    if isinstance(node, ast.Name):
        return node.id == "kind"
    if isinstance(node, ast.Attribute):
        return node.attr == "kind"
    if isinstance(node, ast.Subscript):
        return isinstance(node.slice, ast.Constant) and node.slice.value == "kind"
    return False


def _has_text(node: ast.AST) -> bool:
    """A job kind's name as a string literal, or a tuple / list / set holding one (other kinds, a gripper's
    "parallel" or "suction", are not job kinds)."""
    if isinstance(node, ast.Constant):
        return isinstance(node.value, str) and node.value in KINDS
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        return any(_has_text(e) for e in node.elts)
    return False


def _names_a_kind(node: ast.AST) -> bool:
    if isinstance(node, ast.Compare):
        sides = [node.left, *node.comparators]
        return any(_is_kind(s) for s in sides) and any(_has_text(s) for s in sides)
    if isinstance(node, ast.keyword):
        return node.arg == "kind" and _has_text(node.value)
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and _is_kind(node.func.value):
        return node.func.attr in ("in_", "not_in", "notin_") and any(_has_text(a) for a in node.args)
    if isinstance(node, ast.AnnAssign) and _is_kind(node.target):
        return any(_has_text(n) for n in ast.walk(node.annotation))
    return False


def kind_literals(source: str) -> list[int]:
    """Lines that compare a kind with a string literal, pass one as `kind=`, filter `.kind.in_` / `.not_in` by
    literals, or declare `kind` as a Literal of names."""
    return sorted({node.lineno for node in ast.walk(ast.parse(source)) if _names_a_kind(node)})


def test_the_detector_finds_kind_literals_and_nothing_else():
    bad = [
        'if job.kind == "bulk": pass',
        'q = select(Job.id).where(Job.kind != "bulk")',
        'ok = "cluster" == body.kind',
        'ok = inp.kind in ("generate", "cluster")',
        'ok = row["kind"] == "generate"',
        'job = Job(kind="bulk")',
        'q = Job.kind.not_in(("bulk",))',
        'class R:\n    kind: Literal["generate", "cluster"] = "generate"',
    ]
    for source in bad:
        assert kind_literals(source), source
    good = [
        "if is_container(job.kind): pass",
        "q = select(Job.id).where(Job.kind.not_in(CONTAINER_KINDS), Job.kind == kind)",
        "job = Job(kind=kind.name)",
        'out = {"kind": job.kind}',
        'ok = job.state == "queued"',
    ]
    for source in good:
        assert not kind_literals(source), source


def test_no_module_outside_the_registry_names_a_kind():
    found = {}
    for path in sorted((ROOT / "services").rglob("*.py")):
        if path.is_relative_to(REGISTRY):
            continue
        if lines := kind_literals(path.read_text()):
            found[str(path.relative_to(ROOT))] = lines
    assert found == {}
