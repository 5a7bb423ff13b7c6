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

import hashlib
import math

import torch
from torch import Tensor

from models.ensemble import EnsembleMechanism
from models.gated import GatedMechanism
from models.mechanisms import Mechanism

__all__: list[str] = []


def derived_seed(seed: int, stream: str) -> int:
    """A seed for a named random stream, independent of the main one (no global RNG)."""
    digest = hashlib.sha256(f"pal.fit:{seed}:{stream}".encode()).digest()
    return int.from_bytes(digest[:8], "little") >> 1


def trained(mech: Mechanism) -> Mechanism:
    """The mechanism that fit trains at a site: a gated site's on branch, else the site's own."""
    return mech.on if isinstance(mech, GatedMechanism) else mech


def members(mech: Mechanism) -> list[Mechanism]:
    """The members that fit trains: an ensemble's, or the mechanism (a gated site's on branch)."""
    mech = trained(mech)
    return list(mech.members) if isinstance(mech, EnsembleMechanism) else [mech]


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
    rows = site_rows(site, mech, parents, train_idx)
    if rows is train_idx and not (bootstrap and members > 1):
        return [None] * members
    return epoch_rows(rows, len(train_idx), members, bootstrap, gen)


def epoch_rows(
    rows: Tensor, n_train: int, members: int, bootstrap: bool, gen: torch.Generator
) -> list[Tensor | None]:
    """Per member, ``n_train`` rows drawn from ``rows``: a bootstrap per member of an ensemble, else ``rows`` tiled."""
    if bootstrap and members > 1:
        return [rows[torch.randint(len(rows), (n_train,), generator=gen)] for _ in range(members)]
    tiled = rows.repeat(math.ceil(n_train / len(rows)))[:n_train]
    return [tiled] * members
