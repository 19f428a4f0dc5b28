"""Flow parameters carry the CLI's bounds, so a deployment run with an out-of-range value is
refused before it is created, and a direct call before the flow body runs."""

import importlib

import pytest
from prefect.exceptions import ParameterTypeError
from prefect.utilities.callables import parameter_schema

from flows.corpus import corpus
from flows.loop import loop
from flows.physics import evaluate_physics
from flows.policy import train_policy
from flows.simulate import simulate
from flows.tokenize import tokenize
from flows.train import train

from tests.flows.test_server import LIVE


@pytest.mark.parametrize("flow, name, low", [
    (simulate, "episodes", 1), (train_policy, "episodes", 1), (train, "pretrain_steps", 1),
    (tokenize, "steps", 1), (loop, "worst", 1), (evaluate_physics, "horizon", 1), (train, "self_condition", 0),
])
def test_counts_are_bounded_in_each_deployment_schema(flow, name, low):
    prop = parameter_schema(flow.fn).model_dump()["properties"][name]
    assert prop["minimum"] == low and "maximum" in prop


def test_out_of_range_values_are_refused_before_the_flow_runs():
    for bad in (0, -3):
        with pytest.raises(ParameterTypeError, match="episodes: Input should be greater than or equal to 1"):
            simulate.validate_parameters({"manifest": "m.yaml", "episodes": bad})
    with pytest.raises(ParameterTypeError, match="minutes"):
        corpus.validate_parameters({"minutes": -1})
    assert simulate.validate_parameters({"manifest": "m.yaml", "episodes": 1})["episodes"] == 1


@pytest.mark.parametrize("deployment", LIVE, ids=lambda d: d["name"])
def test_every_shipped_deployment_has_parameters_in_range(deployment):
    path, function = deployment["entrypoint"].split(":")
    flow = getattr(importlib.import_module(path.removesuffix(".py").replace("/", ".")), function)
    flow.validate_parameters(deployment.get("parameters", {}))
