"""Procedural assets of the tabletop scene: object textures (PNG) and the boat's hull mesh (OBJ).

Nothing is downloaded or shipped as binary data: every asset is generated here from a seed and
handed to MuJoCo as an in-memory file (``MjSpec.from_string(xml, assets=...)``), under the file
names that ``assets/tabletop.xml`` references. The same seed gives byte-identical files.

- ``box_cube.png``: a cube texture in MuJoCo's 4x3 cross layout (``gridlayout=".U..LFRB.D.."``),
  each face a different "printed carton" of random shapes, so ORB finds distinct corners on
  every face (a regular checker would make them ambiguous).
- ``boat_hull.png`` / ``boat_hull.obj``: an asymmetric hull (pointed bow, flat transom, one-sided
  stripe and lettering) with texture coordinates along and around it.
- ``boat_cabin.png``: a 2-D texture for the boat's off-centre cabin.
- ``table.png``: faint wood-like grain for the table top.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

__all__ = ["ASSET_NAMES", "boat_hull_obj", "box_cube_texture", "generate_assets", "printed_texture"]

#: File names of the generated assets, as referenced by ``tabletop.xml``.
ASSET_NAMES = ("box_cube.png", "boat_hull.png", "boat_hull.obj", "boat_cabin.png", "table.png")


def _png(image_rgb: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", cv2.cvtColor(image_rgb, cv2.COLOR_RGB2BGR))
    if not ok:  # pragma: no cover - OpenCV always encodes uint8 images
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def printed_texture(
    rng: np.random.Generator,
    size: tuple[int, int],
    background: tuple[int, int, int],
    palette: np.ndarray,
    shapes: int,
) -> np.ndarray:
    """A non-repeating pattern of random filled shapes and strokes, like print on packaging.

    Args:
        rng: source of every random choice.
        size: (height, width) pixels.
        background: RGB of the base colour.
        palette: (k, 3) RGB colours the shapes draw from.
        shapes: number of shapes.

    Returns:
        (height, width, 3) uint8 RGB.
    """
    h, w = size
    img = np.empty((h, w, 3), np.uint8)
    img[:] = background
    scale = min(h, w)
    for _ in range(shapes):
        color = tuple(int(c) for c in palette[rng.integers(len(palette))])
        kind = rng.integers(4)
        cx, cy = int(rng.integers(w)), int(rng.integers(h))
        r = int(rng.uniform(0.03, 0.14) * scale)
        if kind == 0:
            cv2.circle(img, (cx, cy), r, color, -1, cv2.LINE_AA)
        elif kind == 1:
            cv2.rectangle(img, (cx - r, cy - r // 2), (cx + r, cy + r // 2), color, -1, cv2.LINE_AA)
        elif kind == 2:
            pts = np.array(
                [[cx + rng.integers(-r, r + 1), cy + rng.integers(-r, r + 1)] for _ in range(3)], np.int32
            )
            cv2.fillPoly(img, [pts], color, cv2.LINE_AA)
        else:
            end = (cx + int(rng.integers(-2 * r, 2 * r + 1)), cy + int(rng.integers(-2 * r, 2 * r + 1)))
            cv2.line(img, (cx, cy), end, color, max(2, r // 5), cv2.LINE_AA)
    return img


def box_cube_texture(seed: int = 0, face: int = 256) -> np.ndarray:
    """The box's cube texture: (3 face, 4 face, 3) uint8 RGB in the 4x3 cross layout."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 1]))
    palette = np.array(
        [[30, 30, 30], [200, 40, 30], [240, 200, 40], [250, 250, 245], [40, 90, 160], [120, 60, 20]]
    )
    out = np.zeros((3 * face, 4 * face, 3), np.uint8)
    for row, col in ((0, 1), (1, 0), (1, 1), (1, 2), (1, 3), (2, 1)):  # U, L, F, R, B, D
        tile = printed_texture(rng, (face, face), (196, 150, 96), palette, shapes=28)
        cv2.rectangle(tile, (2, 2), (face - 3, face - 3), (90, 60, 30), 3)  # carton edge
        out[row * face : (row + 1) * face, col * face : (col + 1) * face] = tile
    return out


def _hull_profile(
    n_len: int, length: float, beam: float, depth: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stations along the hull: x (stern to bow), half-width at the deck, deck height."""
    s = np.linspace(0.0, 1.0, n_len)
    x = (s - 0.5) * length
    taper = np.where(s < 0.55, 1.0, np.clip(np.cos((s - 0.55) / 0.45 * math.pi / 2.0), 0.0, 1.0) ** 0.8)
    half = 0.5 * beam * np.maximum(taper, 0.0) * (0.92 + 0.08 * np.cos(s * math.pi))
    deck = depth * (1.0 + 0.35 * np.clip((s - 0.6) / 0.4, 0.0, 1.0) ** 2)  # the bow rises
    return x, half, deck


def boat_hull_obj(
    length: float = 0.24, beam: float = 0.10, depth: float = 0.045, n_len: int = 24, n_sec: int = 9
) -> str:
    """Wavefront OBJ text of the hull: a closed mesh in metres, z up, bow towards +x.

    Each station's cross-section runs from the port deck edge down to a keel line and up to
    the starboard deck edge; a flat deck closes the top and a flat transom the stern. Texture
    coordinates: u along the hull, v around the section (deck in v > 0.8).
    """
    x, half, deck = _hull_profile(n_len, length, beam, depth)
    verts: list[tuple[float, float, float]] = []
    uvs: list[tuple[float, float]] = []
    faces: list[tuple[tuple[int, int], ...]] = []
    angles = np.linspace(-math.pi / 2.0, math.pi / 2.0, n_sec)  # port deck edge -> keel -> starboard
    ring = np.zeros((n_len, n_sec), dtype=int)
    for i in range(n_len):
        for j, a in enumerate(angles):
            y = half[i] * math.sin(a)
            z = deck[i] - deck[i] * math.cos(a) ** 1.5 * (
                0.35 + 0.65 * min(1.0, half[i] / (0.5 * beam) + 0.2)
            )
            ring[i, j] = len(verts)
            verts.append((float(x[i]), float(y), float(max(z, 0.0))))
            uvs.append((i / (n_len - 1), 0.8 * j / (n_sec - 1)))
    for i in range(n_len - 1):
        for j in range(n_sec - 1):
            a, b, c, d = ring[i, j], ring[i + 1, j], ring[i + 1, j + 1], ring[i, j + 1]
            faces.append(((a, a), (d, d), (c, c)))
            faces.append(((a, a), (c, c), (b, b)))
    # deck: a fan over port/starboard edges, texture band v in [0.82, 1]
    deck_base = len(verts)
    for i in range(n_len):
        for side in (0, n_sec - 1):
            px, py, pz = verts[ring[i, side]]
            verts.append((px, py, pz))
            uvs.append((i / (n_len - 1), 0.82 + 0.18 * (side / (n_sec - 1))))
    for i in range(n_len - 1):
        p0, s0, p1, s1 = (
            deck_base + 2 * i,
            deck_base + 2 * i + 1,
            deck_base + 2 * i + 2,
            deck_base + 2 * i + 3,
        )
        faces.append(((p0, p0), (p1, p1), (s1, s1)))
        faces.append(((p0, p0), (s1, s1), (s0, s0)))
    # transom at the stern (station 0): a fan from its centre
    centre = len(verts)
    verts.append((float(x[0]), 0.0, float(0.5 * deck[0])))
    uvs.append((0.0, 0.4))
    for j in range(n_sec - 1):
        faces.append(((centre, centre), (ring[0, j + 1], ring[0, j + 1]), (ring[0, j], ring[0, j])))
    top = ((ring[0, n_sec - 1], ring[0, n_sec - 1]), (ring[0, 0], ring[0, 0]))
    faces.append(((centre, centre), *top))
    lines = ["# boat hull generated by pal.sim.tabletop_assets"]
    lines += [f"v {vx:.6f} {vy:.6f} {vz:.6f}" for vx, vy, vz in verts]
    lines += [f"vt {u:.6f} {v:.6f}" for u, v in uvs]
    lines += ["f " + " ".join(f"{vi + 1}/{ti + 1}" for vi, ti in face) for face in faces]
    return "\n".join(lines) + "\n"


def _hull_texture(rng: np.random.Generator, size: int = 512) -> np.ndarray:
    palette = np.array([[250, 250, 250], [20, 40, 90], [230, 120, 30], [30, 140, 120], [10, 10, 10]])
    img = printed_texture(rng, (size, size), (52, 96, 170), palette, shapes=40)
    # a stripe on the port side only (v small): the hull looks different from either side
    cv2.rectangle(img, (0, int(0.62 * size)), (size, int(0.70 * size)), (235, 60, 40), -1)
    cv2.putText(
        img,
        "PAL-7",
        (int(0.3 * size), int(0.85 * size)),
        cv2.FONT_HERSHEY_SIMPLEX,
        2.2,
        (250, 250, 250),
        6,
        cv2.LINE_AA,
    )
    # the deck band (image rows for v > 0.8: OBJ v runs bottom-up): planks with random fittings
    band = int(0.18 * size)
    deck = printed_texture(
        rng,
        (band, size),
        (228, 226, 214),
        np.array([[120, 80, 40], [240, 240, 235], [60, 60, 60], [200, 60, 40], [40, 110, 70]]),
        shapes=45,
    )
    for k in range(0, band, 23):
        cv2.line(deck, (0, k), (size, k), (170, 165, 150), 1)
    img[:band] = deck
    return img


def generate_assets(seed: int = 0) -> dict[str, bytes]:
    """Every generated file of the scene, ``{file name: bytes}`` (see :data:`ASSET_NAMES`)."""
    ss = np.random.SeedSequence([seed, 7])
    hull_rng, cabin_rng, table_rng = (np.random.default_rng(s) for s in ss.spawn(3))
    cabin = printed_texture(
        cabin_rng,
        (256, 256),
        (235, 230, 215),
        np.array([[30, 30, 40], [200, 40, 30], [60, 120, 200], [250, 200, 40]]),
        shapes=26,
    )
    grain = table_rng.normal(0.0, 1.0, (256, 64)).astype(np.float32)
    grain = cv2.GaussianBlur(cv2.resize(grain, (256, 256)), (0, 0), sigmaX=1.0, sigmaY=9.0)
    table = np.clip(
        np.array([170, 135, 95], np.float32) + 9.0 * grain[..., None] / max(float(grain.std()), 1e-6), 0, 255
    )
    return {
        "box_cube.png": _png(box_cube_texture(seed)),
        "boat_hull.png": _png(_hull_texture(hull_rng)),
        "boat_hull.obj": boat_hull_obj().encode("ascii"),
        "boat_cabin.png": _png(cabin),
        "table.png": _png(table.astype(np.uint8)),
    }
