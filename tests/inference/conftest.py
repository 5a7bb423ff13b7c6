import pytest

from models import LinearMechanism, WorldModel, chain_graph


@pytest.fixture
def chain():
    """The analytic oracle X -> Y -> Z: Y = 2X + U_y, Z = -1.5Y + U_z, U ~ N(0, 1), X ~ N(0, 1)."""
    return WorldModel(
        chain_graph(),
        {"y": LinearMechanism.from_coefficients([[2.0]]), "z": LinearMechanism.from_coefficients([[-1.5]])},
    )
