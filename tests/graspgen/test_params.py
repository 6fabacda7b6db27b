"""Params and QualityOptions declare each run parameter once (graspgen/params.py `_option`): validation reads the
declared ranges and choices, generate()'s keywords are the fields with their defaults, and a job's stored params
convert back to the same objects."""

from __future__ import annotations

import inspect
import json
import math
from dataclasses import fields

import pytest

import graspgen
from graspgen import memory
from graspgen.errors import InvalidParameterError
from graspgen.examples import EXAMPLE_GRIPPER, example_part
from graspgen.params import (
    Params,
    QualityOptions,
    from_job,
    from_keywords,
    param_option,
    param_options,
)

#: CONTRACT.md "Python API": generate()'s run keywords and their defaults, as customers call them
CONTRACT_KEYWORDS = {
    "units": None,
    "points": 10_000,
    "friction": None,
    "safety_factor": 1.5,
    "rolls": 16,
    "k1": 16,
    "k2": 4,
    "inside": False,
    "collision": "swept",
    "seed": 0,
    "recording": None,
    "mass_kg": None,
    "density": None,
    "accel": 9.81,
    "hold": "any",
    "position_tolerance": 0.001,
}
#: the job API's documented ranges (docs/API.md, the OpenAPI document): (lowest accepted, highest accepted)
CONTRACT_RANGES = {
    "points": (100, 1_000_000),
    "rolls": (1, 64),
    "k1": (1, 10_000),
    "k2": (1, 1_000),
    "seed": (0, 2**32 - 1),
    "safety_factor": (1.0, 100.0),
    "density": (1.0, 100_000.0),
    "accel": (0.0, 1_000.0),
    "position_tolerance": (0.0, 0.05),
}


def test_generate_lists_every_run_keyword_with_the_fields_default():
    sig = inspect.signature(graspgen.generate)
    assert list(sig.parameters)[:2] == ["mesh_or_path", "gripper"]
    for name, default in CONTRACT_KEYWORDS.items():
        p = sig.parameters[name]
        assert p.kind is inspect.Parameter.KEYWORD_ONLY and p.default == default, name
    for f in (*fields(Params), *fields(QualityOptions)):
        p = sig.parameters[f.name]
        assert p.kind is inspect.Parameter.KEYWORD_ONLY and p.default == f.default, f.name
    assert not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in sig.parameters.values())
    rc = inspect.signature(graspgen.recluster)
    assert rc.parameters["k1"].default is inspect.Parameter.empty and rc.parameters["seed"].default == 0
    for f in fields(QualityOptions):
        assert rc.parameters[f.name].default == f.default, f.name


def test_generate_refuses_unknown_keywords_and_params_given_twice():
    part = example_part("bar")
    with pytest.raises(TypeError, match="unexpected keyword argument 'pionts'"):
        graspgen.generate(part, EXAMPLE_GRIPPER, pionts=500)
    with pytest.raises(TypeError, match="a ready Params or its fields as keywords, not both: k1"):
        graspgen.generate(part, EXAMPLE_GRIPPER, params=Params(), k1=2)
    with pytest.raises(TypeError, match="a ready QualityOptions or its fields as keywords, not both: select"):
        graspgen.recluster("x.npz", {}, k1=1, k2=1, options=QualityOptions(), select="medoid")
    with pytest.raises(TypeError, match="recluster\\(\\) got an unexpected keyword argument 'points'"):
        graspgen.recluster("x.npz", {}, k1=1, k2=1, points=500)
    with pytest.raises(InvalidParameterError, match="points must be between 100 and 1000000, got 99"):
        graspgen.generate(part, EXAMPLE_GRIPPER, points=99)


def test_ready_params_and_keywords_give_the_same_export():
    part = example_part("bar")
    run = {"points": 400, "k1": 3, "k2": 1, "seed": 5, "rolls": 8}
    by_keywords = graspgen.generate(part, EXAMPLE_GRIPPER, **run, select="best-near-medoid")
    ready = graspgen.generate(
        part, EXAMPLE_GRIPPER, params=Params(**run), options=QualityOptions(select="best-near-medoid")
    )
    a, b = by_keywords.to_json(), ready.to_json()
    a["stats"].pop("timings_s"), b["stats"].pop("timings_s")
    assert a == b and a["params"]["rolls"] == 8 and a["grasps"]


def test_the_declared_ranges_are_the_contracts_and_validation_reads_them():
    for name, (lo, hi) in CONTRACT_RANGES.items():
        o = param_option(Params, name)
        assert (o.ge, o.le) == (lo, hi), name
        step = 1 if o.kind is int else 1e-9 * max(1.0, abs(hi))
        for v, ok in ((lo, True), (hi, True), (lo - step, False), (hi + step, False)):
            value = v if o.kind is int else float(v)
            if ok:
                assert getattr(Params(**{name: value}), name) == value
            else:
                with pytest.raises(InvalidParameterError) as err:
                    Params(**{name: value})
                assert err.value.field == name
    # open below: the bound itself is refused
    for name, hi in (("friction", 10.0), ("mass_kg", 100_000.0)):
        assert param_option(Params, name).gt == 0 and param_option(Params, name).le == hi
        with pytest.raises(InvalidParameterError, match=f"{name} must be > 0.0 and <= {hi}, got 0.0"):
            Params(**{name: 0.0})
        assert getattr(Params(**{name: hi}), name) == hi and getattr(Params(**{name: None}), name) is None


@pytest.mark.parametrize(
    "bad, message",
    [
        ({"points": 99}, "points must be between 100 and 1000000, got 99"),
        ({"points": 1.5}, "points must be an integer, got 1.5"),
        ({"rolls": True}, "rolls must be an integer, got True"),
        ({"safety_factor": 0.5}, "safety_factor must be >= 1.0 and <= 100.0, got 0.5"),
        ({"accel": math.nan}, "accel must be a finite number, got nan"),
        ({"density": 0.5}, "density must be >= 1.0 and <= 100000.0, got 0.5"),
        ({"inside": 1}, "inside must be true or false, got 1"),
        ({"collision": "exact"}, "collision must be one of swept, paper, got 'exact'"),
        ({"hold": None}, "hold must be one of any, off, got None"),
        ({"points": None}, "points must be an integer, got None"),
    ],
)
def test_bad_values_are_refused_with_the_same_messages(bad, message):
    with pytest.raises(InvalidParameterError) as err:
        Params(**bad)
    assert err.value.message == message and err.value.field == next(iter(bad))


def test_an_exclusive_group_takes_one_of_its_members():
    with pytest.raises(InvalidParameterError, match="give mass_kg or density, not both") as err:
        Params(mass_kg=1.0, density=1000.0)
    assert err.value.field == "density"
    assert Params(mass_kg=1.0).density is None and Params(density=1000.0).mass_kg is None


def test_every_option_is_a_scalar_with_help_and_a_default_inside_its_range():
    for cls in (Params, QualityOptions):
        for o in param_options(cls):
            assert o.kind in (int, float, bool, str) and o.help, o.name
            assert cls() == cls(**{o.name: o.default})  # the default passes its own checks
            if o.choices:
                assert o.kind is str and o.default in o.choices
    assert [o.name for o in param_options(Params)] == [f.name for f in fields(Params)]
    assert {o.name for o in param_options(QualityOptions)} == set(QualityOptions.JOB_OPTIONS)


def test_a_jobs_stored_params_convert_back():
    stored = {**Params(points=500, density=7850.0).to_dict(friction=0.4), "select": "best-near-medoid"}
    params, options = from_job(json.loads(json.dumps(stored)))  # as the job row's JSON gives them back
    assert params == Params(points=500, density=7850.0, friction=0.4)
    assert options == QualityOptions(select="best-near-medoid")
    assert from_job({"k1": 3}) == (Params(k1=3), QualityOptions())  # stored before the other fields existed
    with pytest.raises(InvalidParameterError, match="unknown parameters colour"):
        from_job({"colour": "red"})
    with pytest.raises(InvalidParameterError, match="validate must be true or false"):
        from_job({"validate": "yes"})


def test_from_keywords_splits_by_class():
    p, q = from_keywords("f", {"k1": 2, "validate": True}, (Params, None), (QualityOptions, None))
    assert p == Params(k1=2) and q == QualityOptions(validate=True)
    ready = Params(points=200)
    p, q = from_keywords("f", {"sim_workers": 2}, (Params, ready), (QualityOptions, None))
    assert p is ready and q.sim_workers == 2


def test_the_probe_runs_with_the_density_fields_only():
    job = Params(points=50_000, friction=0.3, rolls=8, inside=True, k1=40, seed=7, mass_kg=2.0, hold="off")
    run = memory.probe_params(job)
    assert run == Params(points=memory.PROBE_POINTS, k1=1, k2=1, friction=0.3, rolls=8, inside=True)
    assert memory.probe_params(Params(points=300, k2=9)) == memory.probe_params(Params())
