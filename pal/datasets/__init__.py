"""Real tables with textbook causal answers, shipped as package data (``tables/SOURCE.md``).

* :func:`lalonde`: the National Supported Work experiment (LaLonde 1986; the Dehejia and
  Wahba 1999 sample), with its experimental controls or with the Current Population Survey
  controls. The experimental effect of training on 1978 earnings is :data:`NSW_EFFECT` USD.
* :func:`nhefs`: NHEFS (Hernán and Robins, *Causal Inference: What If*, ch. 12-13); the
  average effect of quitting smoking on the 1971-1982 weight change is about
  :data:`NHEFS_EFFECT` kg.

Each returns an ordered mapping column -> 1-d float64 array (binary columns are 0/1), which
:func:`models.tables.as_table` and every query take; ``pandas.DataFrame(columns)`` makes a
DataFrame of it. The data are converted from the PyPI package ``causaldata`` 0.1.5 (MIT
licence); nothing is downloaded at run time.
"""

from __future__ import annotations

import csv
import gzip
import io
from importlib import resources

import numpy as np

__all__ = ["NHEFS_EFFECT", "NSW_EFFECT", "lalonde", "nhefs", "read_table"]

#: Experimental effect of NSW training on 1978 earnings (difference in means), USD.
NSW_EFFECT = 1794.34
#: Average effect of quitting smoking on weight change (IP weighting, standardisation), kg.
NHEFS_EFFECT = 3.4

_FILES = ("nsw_mixtape.csv", "cps_mixtape.csv.gz", "nhefs_complete.csv")
_NSW_COLUMNS = ("treat", "age", "educ", "black", "hisp", "marr", "nodegree", "re74", "re75", "re78")


def read_table(name: str) -> dict[str, np.ndarray]:
    """Every numeric column of one shipped table: column -> ``(N,)`` float64 (empty cells refused).

    Raises:
        ValueError: an unknown table name, or a non-numeric cell in a numeric column.
    """
    if name not in _FILES:
        raise ValueError(f"unknown table {name!r}; shipped: {list(_FILES)}")
    raw = resources.files("pal.datasets").joinpath("tables", name).read_bytes()
    if name.endswith(".gz"):
        raw = gzip.decompress(raw)
    rows = list(csv.reader(io.StringIO(raw.decode("utf-8"))))
    header, body = rows[0], rows[1:]
    out: dict[str, np.ndarray] = {}
    for j, col in enumerate(header):
        cells = [r[j] for r in body]
        if col == "data_id":  # the sample's label, the same text on every row
            continue
        try:
            out[col] = np.array([float(c) for c in cells])
        except ValueError as err:
            raise ValueError(f"table {name!r}, column {col!r}: {err}") from None
    return out


def lalonde(controls: str = "cps") -> dict[str, np.ndarray]:
    """NSW trainees with experimental (``"nsw"``, 445 rows) or CPS (``"cps"``, 16 177 rows) controls.

    Columns: treat (0/1), age (years), educ (years), black, hisp, marr, nodegree (0/1),
    re74, re75, re78 (earnings, USD).

    Raises:
        ValueError: ``controls`` other than ``"cps"`` or ``"nsw"``.
    """
    if controls not in ("cps", "nsw"):
        raise ValueError(f"controls must be 'cps' or 'nsw', got {controls!r}")
    nsw = read_table("nsw_mixtape.csv")
    if controls == "nsw":
        return {c: nsw[c] for c in _NSW_COLUMNS}
    cps = read_table("cps_mixtape.csv.gz")
    trained = nsw["treat"] == 1
    return {c: np.concatenate([nsw[c][trained], cps[c]]) for c in _NSW_COLUMNS}


def nhefs() -> dict[str, np.ndarray]:
    """NHEFS complete cases, 1566 rows.

    Columns: seqn (row id), qsmk (quit smoking, 0/1), wt82_71 (weight change, kg), sex,
    race (0/1), age (years), education (codes 1-5), smokeintensity (cigarettes a day),
    smokeyrs (years), exercise, active (codes 0-2), wt71 (kg).
    """
    return read_table("nhefs_complete.csv")
