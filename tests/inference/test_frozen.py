"""Queries leave the world model's parameters as they found them: no gradients, no flags changed."""

import pytest
import torch

from inference import SVIOptions, infer_action, infer_state
from inference.frozen import frozen_parameters
from models import WorldModel, finger_graph


# few SVI steps on purpose: the test checks gradients, not the posterior
@pytest.mark.filterwarnings("ignore::inference.PoorPosteriorWarning")
def test_infer_state_accumulates_no_gradient_in_the_model(chain):
    flags = [p.requires_grad for p in chain.parameters()]
    assert any(flags)
    infer_state(
        chain,
        {"x": torch.ones(4, 1), "z": -2 * torch.ones(4, 1)},
        num_steps=5,
        options=SVIOptions(num_particles=2),
    )
    assert all(p.grad is None for p in chain.parameters())
    assert [p.requires_grad for p in chain.parameters()] == flags


def test_infer_action_accumulates_no_gradient_in_the_model():
    m = WorldModel(finger_graph("thesis"))
    infer_action(m, {"q_prev.finger": torch.zeros(3, 1)}, {"q.finger": torch.ones(3, 1)}, num_steps=5)
    assert all(p.grad is None for p in m.parameters())
    assert all(p.requires_grad for p in m.parameters())


def test_flags_are_restored_after_an_error():
    layer = torch.nn.Linear(2, 2)
    layer.bias.requires_grad_(False)
    try:
        with frozen_parameters(layer):
            assert not any(p.requires_grad for p in layer.parameters())
            raise RuntimeError("boom")
    except RuntimeError as err:
        assert str(err) == "boom"
    assert layer.weight.requires_grad
    assert not layer.bias.requires_grad


def test_non_modules_pass_through():
    def program():
        return None

    with frozen_parameters(program) as same:
        assert same is program
