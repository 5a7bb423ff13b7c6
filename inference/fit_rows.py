"""Which rows of the data train each mechanism of :func:`inference.fit`.

Every site trains on the training rows, and each member of an ensemble on its own bootstrap
of them. A gated site (:class:`models.GatedMechanism`) trains its on branch only, on the rows
where its switch is on, so that rare pushes are not drowned by the many rows where the switch
is off (those are the off branch's, whose mean and floor sigma_0 stay as given):

    rows(X) = {r in train : c_r = 1},      normalisers, losses, bootstraps, sigma and the
                                           scale recalibration all from those rows.

The on rows are tiled to the number of training rows (each epoch passes over each on row
about ``n_train / n_on`` times, in minibatches of on rows only), so the on branch takes as
many Adam steps as any other site.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from models.gated import GatedMechanism
from models.mechanisms import Mechanism

__all__: list[str] = []


def trained(mech: Mechanism) -> Mechanism:
    """The mechanism that fit trains at a site: a gated site's on branch, else the site's own."""
    return mech.on if isinstance(mech, GatedMechanism) else mech


def site_rows(site: str, mech: Mechanism, parents: Tensor, idx: Tensor, what: str = "training") -> Tensor:
    """The rows of ``idx`` that train ``mech``: those where a gated site's switch is on, else all.

    Raises:
        ValueError: a gated site with no ``what`` row where its switch is on.
    """
    if not isinstance(mech, GatedMechanism) or len(idx) == 0:
        return idx
    on = idx[mech.switch_on(parents[idx])]
    if what == "training" and len(on) == 0:
        raise ValueError(
            f"gated site {site!r}: its switch {mech.switch!r} is on in none of the {len(idx)} training rows; "
            "the on branch needs rows where the switch is 1"
        )
    return on


def member_rows(
    site: str,
    mech: Mechanism,
    parents: Tensor,
    train_idx: Tensor,
    members: int,
    bootstrap: bool,
    gen: torch.Generator,
) -> list[Tensor | None]:
    """Per member, the ``n_train`` row indices it trains on in an epoch (None: the minibatch rows).

    A bootstrap member of an ensemble draws ``n_train`` rows with replacement from its site's
    rows; a gated site's rows are its on rows (tiled, or drawn from when bootstrapping).
    """
    n_train = len(train_idx)
    rows = site_rows(site, mech, parents, train_idx)
    use = bootstrap and members > 1
    if use:
        return [rows[torch.randint(len(rows), (n_train,), generator=gen)] for _ in range(members)]
    if rows is train_idx:
        return [None] * members
    tiled = rows.repeat(math.ceil(n_train / len(rows)))[:n_train]
    return [tiled] * members
