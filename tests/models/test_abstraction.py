"""Abstraction variables (Eq. 6.2): built-in mechanisms on trajectories with known answers, and queries on a layer."""

import pytest
import torch

from inference import counterfactual, do, infer_action, infer_state
from models import CausalGraph, LinearMechanism, Variable, WorldModel
from models.abstraction import (
    Abstraction,
    ContactOnset,
    Displacement,
    Moving,
    Opening,
    ReachCompleted,
    WindowError,
    abstract,
)
from models.abstraction_learned import MotorPrimitive, TemporalEncoder


def _flag(name: str, support: tuple[str, ...], window: int, mech) -> Abstraction:
    return Abstraction(name, support, window, mech, Variable(name, "observed", 1))


def test_contact_onset_index() -> None:
    touch = torch.zeros(10, 1)
    touch[6:] = 1.0
    z = abstract({"touch": touch}, [_flag("onset", ("touch",), 2, ContactOnset("touch"))])["onset"]
    assert z.shape == (9, 1)
    assert torch.nonzero(z[:, 0]).flatten().tolist() == [5]  # row t = onset at t + 1 = 6


def test_moving_and_opening() -> None:
    x = torch.zeros(8, 2)
    x[4:, 0] = torch.arange(4.0) * 0.1  # still until step 4, then 0.1 per step
    out = abstract(
        {"x": x},
        [
            _flag("moving", ("x",), 2, Moving("x", speed=0.05)),
            _flag("opening", ("x",), 3, Opening("x", rise=0.15, index=0)),
        ],
    )
    assert out["moving"][:, 0].tolist() == [0, 0, 0, 0, 1, 1, 1]
    assert out["opening"][:, 0].tolist() == [0, 0, 0, 0, 1, 1]


def test_reach_completed() -> None:
    t = torch.linspace(0, 1, 11)[:, None]
    ee = torch.cat([0.2 * (1 - (1 - t) ** 3), torch.zeros(11, 1)], 1)  # decelerates into (0.2, 0)
    a = _flag("reached", ("ee",), 2, ReachCompleted("ee", (0.2, 0.0), radius=0.005, speed=0.002))
    z = abstract({"ee": ee}, [a])["reached"][:, 0]
    first = int(torch.nonzero(z).flatten()[0])
    dist = (ee[:, 0] - 0.2).abs()
    assert dist[first + 1] <= 0.005 and (ee[first + 1] - ee[first]).norm() <= 0.002  # both hold at the end
    assert not (dist[first] <= 0.005 and (ee[first] - ee[max(first - 1, 0)]).norm() <= 0.002)  # not earlier
    assert z[-1] == 1 and z[0] == 0


def test_window_longer_than_history() -> None:
    a = _flag("d", ("x",), 6, Displacement("x"))
    with pytest.raises(WindowError, match="window of 6 steps is longer than the history of 4 steps"):
        abstract({"x": torch.zeros(4, 1)}, [a])
    assert issubclass(WindowError, ValueError)


def test_bad_abstractions() -> None:
    with pytest.raises(ValueError, match="names must agree"):
        Abstraction("a", ("x",), 2, Displacement("x"), Variable("b", "observed", 1))
    wrong = Abstraction("d", ("x",), 2, Displacement("x"), Variable("d", "observed", 3))
    with pytest.raises(ValueError, match=r"expected \(3, 3\)"):
        abstract({"x": torch.zeros(4, 1)}, [wrong])
    with pytest.raises(ValueError, match="history has no variable 'y'"):
        abstract(
            {"x": torch.zeros(4, 1)},
            [Abstraction("d", ("y",), 2, Displacement("y"), Variable("d", "observed", 1))],
        )


def test_motor_primitive_reconstruction_and_inverse() -> None:
    prim = MotorPrimitive("q", window=20, n_basis=6)
    w = torch.randn(3, 6, 2, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    traj = prim.generate(w)  # in the span of the basis
    assert torch.allclose(prim.weights(traj), w, atol=1e-8)  # inverse exact
    s = torch.linspace(0, 1, 20, dtype=torch.float64)
    smooth = torch.stack([0.5 * (1 - torch.cos(torch.pi * s)), 0.3 * s**2], -1)[None]  # a reach, rad
    assert float(prim.error(smooth)) < 0.01
    a = Abstraction("prim", ("q",), 20, prim, Variable("prim", "observed", 12))
    assert abstract({"q": smooth[0]}, [a])["prim"].shape == (1, 12)


def test_temporal_encoder_fit_reduces_loss() -> None:
    g = torch.Generator().manual_seed(0)
    x = torch.randn(64, 5, 2, generator=g, dtype=torch.float64)
    enc = TemporalEncoder(("x",), (2,), window=5, dim=2, hidden=(16,), seed=0)
    losses = enc.fit({"x": x}, x[:, -1], epochs=150, lr=0.02)  # learn to report the window's end state
    assert losses[-1] < 0.2 * losses[0]
    assert enc({"x": x}).shape == (64, 2)


def _event_layer() -> WorldModel:
    """A layer over abstractions: push extent (action) -> displacement d = 1.0 * extent -> moved = 2 d."""
    g = CausalGraph(
        [
            Variable("extent", "action", 1, bounds=(-1, 1)),
            Variable("d", "observed", 1),
            Variable("moved", "observed", 1),
        ],
        [("extent", "d"), ("d", "moved")],
    )
    return WorldModel(
        g,
        {
            "d": LinearMechanism.from_coefficients([[1.0]], sigma=0.1),
            "moved": LinearMechanism.from_coefficients([[2.0]], sigma=0.1),
        },
    )


@pytest.mark.slow
def test_queries_on_a_layer_graph() -> None:
    m = _event_layer()
    out = do(m, {"extent": torch.tensor([[0.3]])})(None, 1)
    assert out["extent"].item() == pytest.approx(0.3)
    act = infer_action(m, None, {"moved": torch.tensor([[0.8]])}, num_steps=300)
    assert act.actions["extent"].item() == pytest.approx(0.4, abs=0.02)
    cf = counterfactual(
        m,
        {"extent": torch.tensor([[0.2]]), "d": torch.tensor([[0.25]]), "moved": torch.tensor([[0.5]])},
        {"extent": torch.tensor([[0.5]])},
    )
    # abducted u_d = 0.05, u_moved = 0: d' = 0.55, moved' = 1.1
    assert cf.mean["moved"].item() == pytest.approx(1.1, abs=1e-4)
    latent = m.with_graph(
        CausalGraph([m.graph["extent"], Variable("d", "latent", 1), m.graph["moved"]], m.graph.edges)
    )
    post = infer_state(
        latent, {"extent": torch.tensor([[0.2]]), "moved": torch.tensor([[0.6]])}, num_steps=400, seed=0
    )
    # Gaussian posterior of d: prior N(0.2, 0.01), obs 2 d + N(0, 0.01) = 0.6 -> mean 0.28
    assert post.mean["d"].item() == pytest.approx(0.28, abs=0.03)
