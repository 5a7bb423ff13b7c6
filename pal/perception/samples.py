"""Real RGB-D sample frames shipped with pal (package data in ``sample_data/``, see its README).

- ``"tum_desk"``: two frames of a static office desk from the TUM freiburg2 camera (paired
  files, depth 1/5000 m per unit), no ground truth;
- ``"kinect_room"``: three frames of a static room from a Kinect (``color/`` + ``depth/``
  16-bit PNG, depth in millimetres) with approximate camera poses (``pose.txt``).

Both sets carry their ``calibration.json`` (intrinsics, depth scale, a nominal 30 frames/s).
Licences: MIT (slambook2) and CC BY 4.0 (TUM RGB-D benchmark); see ``sample_data/README.md``.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from pal.io.files import read_json
from pal.perception.folders import FolderSequence

__all__ = ["SAMPLES", "open_sample", "sample_path", "support_regions"]

#: The sample sets, by name.
SAMPLES: tuple[str, ...] = ("tum_desk", "kinect_room")


def sample_path(name: str) -> Path:
    """Directory of the sample set ``name`` (one of :data:`SAMPLES`).

    Raises:
        ValueError: an unknown name.
        FileNotFoundError: the package was installed without its sample data.
    """
    if name not in SAMPLES:
        raise ValueError(f"unknown sample {name!r}; expected one of {list(SAMPLES)}")
    path = Path(str(resources.files("pal.perception").joinpath("sample_data", name)))
    if not (path / "calibration.json").is_file():
        raise FileNotFoundError(
            f"{path} is missing: this installation of pal has no sample data (install it from the source tree)"
        )
    return path


def open_sample(name: str) -> FolderSequence:
    """The sample set ``name`` as a :class:`FolderSequence` (calibration read from its file)."""
    return FolderSequence(sample_path(name))


def support_regions(name: str) -> tuple[str, dict[str, tuple[int, int, int, int]]]:
    """The sample's support surface and, per frame stem, a pixel box showing only it.

    Returns:
        (surface name, ``{stem: (x0, y0, x1, y1)}``) from ``support.json`` (see the README).
    """
    data = read_json(sample_path(name) / "support.json")
    regions = {str(k): (int(v[0]), int(v[1]), int(v[2]), int(v[3])) for k, v in data["regions"].items()}
    return str(data["surface"]), regions
