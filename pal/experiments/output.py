"""Writing experiment artifacts: JSON, markdown and PNG, each written atomically."""

from __future__ import annotations

import io
import json
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from models.io import atomic_write, versions

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["jsonable", "save_figure", "write_json", "write_outputs"]


def jsonable(value: Any) -> Any:
    """Convert tensors, arrays, numpy scalars and tuples to JSON types; NaN/inf become None."""
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()
    if hasattr(value, "tolist") and not isinstance(value, (str, bytes)):
        value = value.tolist()
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_json(path: str | os.PathLike[str], data: Any) -> Path:
    text = json.dumps(jsonable(data), indent=2, sort_keys=True) + "\n"
    return atomic_write(path, lambda fh: fh.write(text.encode()))


def save_figure(fig: Figure, path: str | os.PathLike[str], dpi: int = 120) -> Path:
    """Render ``fig`` to PNG atomically and close it."""
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return atomic_write(path, lambda fh: fh.write(buf.getvalue()))


def write_outputs(
    out_dir: str | os.PathLike[str],
    name: str,
    result: Mapping[str, Any],
    markdown: str | None = None,
    figures: Mapping[str, Figure] | None = None,
    config: Mapping[str, Any] | None = None,
) -> dict[str, Path]:
    """Write ``{name}.json`` (with provenance), ``{name}.md`` and ``{name}_{fig}.png``."""
    out = Path(out_dir)
    paths = {
        "json": write_json(
            out / f"{name}.json", {"result": result, "config": config or {}, "versions": versions()}
        )
    }
    if markdown is not None:
        paths["markdown"] = atomic_write(out / f"{name}.md", lambda fh: fh.write(markdown.encode()))
    for key, fig in (figures or {}).items():
        paths[key] = save_figure(fig, out / f"{name}_{key}.png")
    return paths
