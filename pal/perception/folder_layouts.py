"""Naming patterns of folders of RGB-D image files: which colour file goes with which depth file.

A :class:`FolderLayout` names the colour and the depth file of one frame by two templates
relative to the folder, each with one ``{stem}`` and without the extension:

==================  ===================  ===================  ==============================
name                colour               depth                example
==================  ===================  ===================  ==============================
``paired``          ``{stem}``           ``{stem}_depth``     ``1.png`` + ``1_depth.png``
``dashed``          ``{stem}-color``     ``{stem}-depth``     ``1-color.png`` + ``1-depth.png``
``subfolders``      ``color/{stem}``     ``depth/{stem}``     ``color/1.jpg`` + ``depth/1.png``
``rgb-subfolders``  ``rgb/{stem}``       ``depth/{stem}``     ``rgb/1.png`` + ``depth/1.pgm``
==================  ===================  ===================  ==============================

Colour files have one of :data:`COLOR_EXTENSIONS`, depth files one of
:data:`DEPTH_EXTENSIONS`. When both templates name the same directory, a file that both match
(``1_depth.png`` matches ``{stem}`` too) belongs to the more specific one, the template with
more literal characters. A folder is read only when its colour and depth stems are the same
set: an unpaired file is an error that names it, not a frame silently dropped.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from pal.io.sequence_files import SequenceError

__all__ = [
    "COLOR_EXTENSIONS",
    "DEPTH_EXTENSIONS",
    "LAYOUTS",
    "FolderLayout",
    "find_layout",
    "layout_named",
    "match_layout",
    "paired_frames",
]

#: Colour image file extensions, lower case.
COLOR_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".ppm", ".tif", ".tiff")
#: Depth image file extensions (16-bit), lower case.
DEPTH_EXTENSIONS = (".png", ".pgm")
_STEM = "{stem}"


def _check_template(name: str, role: str, template: object) -> str:
    if not isinstance(template, str) or template.count(_STEM) != 1:
        raise ValueError(
            f"layout {name!r}: the {role} template {template!r} must hold '{{stem}}' exactly once"
        )
    parts = Path(template).parts
    if Path(template).is_absolute() or ".." in parts or _STEM not in parts[-1]:
        raise ValueError(
            f"layout {name!r}: the {role} template {template!r} must be relative to the folder, without "
            "'..', with '{stem}' in the file name"
        )
    return template


@dataclass(frozen=True)
class FolderLayout:
    """How a frame's colour and depth files are named (module docstring).

    Args:
        name: the layout's name, e.g. ``"dashed"``.
        color: colour template relative to the folder, one ``{stem}``, no extension.
        depth: depth template, likewise.
    """

    name: str
    color: str
    depth: str

    def __post_init__(self) -> None:
        _check_template(self.name, "colour", self.color)
        _check_template(self.name, "depth", self.depth)
        if self.color == self.depth:
            raise ValueError(f"layout {self.name!r}: colour and depth templates are both {self.color!r}")

    def describe(self) -> str:
        """``'<color>.<ext> + <depth>.<ext>'``, for messages."""
        return f"{self.color}.<ext> + {self.depth}.<ext>"


#: The built-in layouts, in the order :func:`match_layout` tries them.
LAYOUTS = (
    FolderLayout("subfolders", "color/{stem}", "depth/{stem}"),
    FolderLayout("rgb-subfolders", "rgb/{stem}", "depth/{stem}"),
    FolderLayout("paired", "{stem}", "{stem}_depth"),
    FolderLayout("dashed", "{stem}-color", "{stem}-depth"),
)


def layout_named(layout: str | FolderLayout) -> FolderLayout:
    """A :class:`FolderLayout`, or the built-in one of that name (ValueError naming the choices)."""
    if isinstance(layout, FolderLayout):
        return layout
    for known in LAYOUTS:
        if known.name == layout:
            return known
    raise ValueError(
        f"layout {layout!r} is unknown; expected a FolderLayout or one of {[x.name for x in LAYOUTS]}"
    )


def _affixes(template: str) -> tuple[str, str, str]:
    directory, name = os.path.split(template)
    prefix, suffix = name.split(_STEM)
    return directory, prefix, suffix


def _stem_of(file_stem: str, prefix: str, suffix: str) -> str | None:
    if (
        len(file_stem) > len(prefix) + len(suffix)
        and file_stem.startswith(prefix)
        and file_stem.endswith(suffix)
    ):
        return file_stem[len(prefix) : len(file_stem) - len(suffix)]
    return None


def _files(folder: Path, template: str, extensions: tuple[str, ...], other: str | None) -> dict[str, Path]:
    """Files of ``template`` by stem; ``other``: a template in the same directory that is more specific."""
    directory, prefix, suffix = _affixes(template)
    where = folder / directory
    if not where.is_dir():
        return {}
    rival = None if other is None else _affixes(other)[1:]
    out: dict[str, Path] = {}
    for p in sorted(where.iterdir()):
        if not (p.is_file() and p.suffix.lower() in extensions):
            continue
        stem = _stem_of(p.stem, prefix, suffix)
        if stem is not None and (rival is None or _stem_of(p.stem, *rival) is None):
            out[stem] = p
    return out


def _order(stems: set[str]) -> list[str]:
    if all(s.lstrip("-").isdigit() for s in stems):
        return sorted(stems, key=int)
    return sorted(stems)


def _specific(template: str) -> int:
    return len(template.replace(_STEM, ""))


def match_layout(folder: Path, layout: FolderLayout) -> tuple[dict[str, Path], dict[str, Path]]:
    """Colour and depth files of ``layout`` in ``folder``, each by stem (possibly unpaired)."""
    same = _affixes(layout.color)[0] == _affixes(layout.depth)[0]
    more_specific = _specific(layout.depth) > _specific(layout.color)
    color = _files(folder, layout.color, COLOR_EXTENSIONS, layout.depth if same and more_specific else None)
    depth = _files(
        folder, layout.depth, DEPTH_EXTENSIONS, layout.color if same and not more_specific else None
    )
    return color, depth


def paired_frames(folder: Path, layout: FolderLayout) -> list[tuple[str, Path, Path]]:
    """``(stem, colour file, depth file)`` of every frame in order.

    Raises:
        SequenceError: the layout matches no file, or colour and depth stems differ (names the
            folder, the pattern, the counts and the first unpaired stems).
    """
    color, depth = match_layout(folder, layout)
    if not color and not depth:
        raise SequenceError(f"{folder}: the layout {layout.name!r} ({layout.describe()}) matches no file")
    if set(color) != set(depth):
        alone_c, alone_d = _order(set(color) - set(depth)), _order(set(depth) - set(color))
        raise SequenceError(
            f"{folder}: layout {layout.name!r} ({layout.describe()}) finds {len(color)} colour and "
            f"{len(depth)} depth files; colour without depth: {alone_c[:5]}, depth without colour: "
            f"{alone_d[:5]}; every frame needs both"
        )
    return [(s, color[s], depth[s]) for s in _order(set(color))]


def find_layout(folder: Path) -> FolderLayout | None:
    """The built-in layout that pairs the most files in ``folder`` (the first on ties), or None."""
    best, best_count = None, 0
    for layout in LAYOUTS:
        color, depth = match_layout(folder, layout)
        count = len(set(color) & set(depth))
        if count > best_count:
            best, best_count = layout, count
    return best
