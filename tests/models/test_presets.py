"""The pushing world-model graph."""

import pytest
import torch

from models import Role, WorldModel
from models.presets import pushing_graph

RANGES = {"shoulder": (-1.0, 1.0), "elbow": (-1.0, 0.5)}


def test_pushing_chain_from_actions_to_perceived_positions():
    g = pushing_graph(["shoulder", "elbow"], RANGES, ["box", "ball"])
    assert set(g.parents("hand")) == {"q.shoulder", "q.elbow"}
    assert set(g.parents("hand_prev")) == {"q_prev.shoulder", "q_prev.elbow"}
    assert set(g.parents("contact.box")) == {"hand_prev", "hand", "pos_prev.box"}
    assert set(g.parents("dpos.box")) == {"contact.box", "hand_prev", "hand", "pos_prev.box"}
    assert set(g.parents("pos.box")) == {"pos_prev.box", "dpos.box"}
    assert g.parents("meas.box") == ("pos.box",)
    assert g["meas.box"].role is Role.OBSERVED and g["pos.box"].role is Role.LATENT
    assert {g[n].dim for n in ("pos.box", "dpos.ball", "meas.ball")} == {2}
    # every action reaches every object position
    for o in ("box", "ball"):
        assert {"act.shoulder", "act.elbow"} <= g.ancestors(f"pos.{o}")
    # objects do not push each other in this graph
    assert "pos_prev.ball" not in g.ancestors("pos.box")


def test_pushing_model_samples_every_site():
    m = WorldModel(pushing_graph(["shoulder"], RANGES, object_dim=3))
    values = m.sample(5, torch.Generator().manual_seed(0))
    assert values["pos.box"].shape == (5, 3) and values["hand"].shape == (5, 3)
    assert all(torch.isfinite(v).all() for v in values.values())


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"objects": ()}, "objects is empty"),
        ({"objects": ("hand",)}, "clash with the hand"),
        ({"object_dim": 4}, "object_dim must be 2"),
    ],
)
def test_bad_pushing_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        pushing_graph(["shoulder"], RANGES, **kwargs)
