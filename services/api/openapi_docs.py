"""The OpenAPI document's finishing: the contract's typed payloads as named components, and every error response as
`application/problem+json` (FastAPI documents its own 422 as plain JSON with a schema the API never sends)."""

from __future__ import annotations

from typing import Any

from pydantic.json_schema import models_json_schema

from .contract_schemas import DOCUMENT_MODELS
from .problems import PROBLEM_JSON

__all__ = ["document_contract", "REF"]

REF = "#/components/schemas/{model}"
_PROBLEM = {PROBLEM_JSON: {"schema": {"$ref": REF.format(model="Problem")}}}
_FASTAPI_VALIDATION = ("HTTPValidationError", "ValidationError")


def document_contract(schema: dict[str, Any]) -> None:
    components = schema.setdefault("components", {}).setdefault("schemas", {})
    _, defs = models_json_schema([(m, "validation") for m in DOCUMENT_MODELS], ref_template=REF)
    for name, body in defs.get("$defs", {}).items():
        components.setdefault(name, body)
    for ops in schema.get("paths", {}).values():
        for op in ops.values():
            for code, response in op.get("responses", {}).items():
                if code[:1] in ("4", "5"):
                    content = response.get("content") or {}
                    if set(content) != {PROBLEM_JSON} or "schema" not in content[PROBLEM_JSON]:
                        response["content"] = {**_PROBLEM}
    text = repr(schema["paths"])
    for name in _FASTAPI_VALIDATION:
        if f"/{name}'" not in text:
            components.pop(name, None)
