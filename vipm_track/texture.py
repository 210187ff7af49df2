"""Aperiodic ground textures built from real photographs, with a mip-map pyramid.

A :class:`GroundTexture` is a large square canvas of texels (uint8 grey) laid on the ground
plane of the world at ``metres_per_texel``. The canvas is built from randomly cropped,
flipped and rotated copies of one photograph, blended across tile borders with a
variance-preserving feather (so the seams keep the photo's contrast) and wrapped
toroidally: sampling modulo the canvas size is seamless, and the period (the canvas size,
tens of metres) is far larger than what one camera frame sees.

Texel (u, v) of level 0 covers world X ∈ [u, u+1)·mpt, Z ∈ (-(v+1), -v]·mpt (image up is
world forward), texel centres at integer coordinates as OpenCV samples them.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from .resources import data_path


@dataclass(frozen=True)
class TextureRecipe:
    """How a named texture is made from a photo: contrast scale around the mean, Gaussian
    blur of the photo in texels (removes high-pass content), brightness of the mean, and
    whether 90° rotations are allowed (not for bricks, whose rows must stay horizontal)."""

    photo: str
    contrast: float = 1.0
    blur_texels: float = 0.0
    mean: float | None = None
    rotations: bool = True


#: Named textures; ``corridor`` is the paper's weak-texture case (polished floor: low
#: contrast, little high-frequency content).
TEXTURES: dict[str, TextureRecipe] = {
    "gravel": TextureRecipe("gravel.png"),
    "grass": TextureRecipe("grass.png"),
    "brick": TextureRecipe("brick.png", rotations=False),
    "corridor": TextureRecipe("gravel.png", contrast=0.12, blur_texels=2.5, mean=170.0),
}


class GroundTexture:
    """A wrapped texture canvas on the ground with its mip-map pyramid.

    Parameters
    ----------
    canvas : (S, S) uint8 array
        Level-0 texels; the canvas is treated as periodic (toroidal).
    metres_per_texel : float
        Size of one level-0 texel on the ground [m].
    name : str
        For messages and metadata.
    """

    def __init__(self, canvas: NDArray, metres_per_texel: float, name: str = "custom") -> None:
        canvas = np.asarray(canvas)
        if canvas.ndim != 2 or canvas.shape[0] < 8 or canvas.shape[1] < 8:
            raise ValueError(f"texture canvas must be 2-D, at least 8×8; got {canvas.shape}")
        if not metres_per_texel > 0:
            raise ValueError(f"metres_per_texel must be > 0, got {metres_per_texel}")
        self.name = name
        self.metres_per_texel = float(metres_per_texel)
        self.levels: list[NDArray[np.uint8]] = _pyramid(np.clip(canvas, 0, 255).astype(np.uint8))

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of level 0, texels."""
        return self.levels[0].shape[1], self.levels[0].shape[0]

    @property
    def period_m(self) -> tuple[float, float]:
        """Repetition period of the texture along world X and Z, metres."""
        w, h = self.size
        return w * self.metres_per_texel, h * self.metres_per_texel

    @property
    def n_levels(self) -> int:
        return len(self.levels)

    @classmethod
    def from_photo(
        cls,
        photo: str | Path | NDArray,
        metres_per_texel: float,
        tiles: int = 24,
        seed: int = 0,
        recipe: TextureRecipe | None = None,
        tile_size: int = 320,
        overlap: int = 64,
        name: str | None = None,
    ) -> GroundTexture:
        """Aperiodic canvas of ``tiles`` × ``tiles`` feathered tiles cut from a photo.

        Each tile is a random ``tile_size`` crop of the photo under a random flip/rotation;
        neighbours overlap by ``overlap`` texels. Deterministic from ``seed``. The canvas is
        ``tiles · (tile_size - overlap)`` texels wide.
        """
        recipe = recipe or TextureRecipe(str(photo) if not isinstance(photo, np.ndarray) else "")
        img = _load_photo(photo) if not isinstance(photo, np.ndarray) else np.asarray(photo, float)
        if recipe.blur_texels > 0:
            img = cv2.GaussianBlur(img, (0, 0), recipe.blur_texels)
        if min(img.shape) < tile_size:
            raise ValueError(f"photo of {img.shape[1]}×{img.shape[0]} px is smaller than the "
                             f"tile size {tile_size}")
        step = tile_size - overlap
        if step <= 0 or tiles < 2:
            raise ValueError("need overlap < tile_size and at least 2 tiles")
        mean = float(img.mean())
        centred = (img - mean).astype(np.float32)
        size = tiles * step
        ramp = np.clip((np.minimum(np.arange(tile_size), tile_size - 1 - np.arange(tile_size))
                        + 0.5) / overlap, 0.0, 1.0).astype(np.float32)
        weight = np.outer(ramp, ramp)
        # Σ weight² over the wrapped tiles is separable and periodic with the step.
        den_1d = np.zeros(size, np.float32)
        for i in range(tiles):
            np.add.at(den_1d, (i * step + np.arange(tile_size)) % size, ramp * ramp)
        num = np.zeros((size, size), np.float32)
        rng = np.random.default_rng(seed)
        n_orient = 8 if recipe.rotations else 4
        for i in range(tiles):
            rows = (i * step + np.arange(tile_size)) % size
            strip = np.zeros((tile_size, size), np.float32)
            for j in range(tiles):
                oy = rng.integers(0, img.shape[0] - tile_size + 1)
                ox = rng.integers(0, img.shape[1] - tile_size + 1)
                crop = centred[oy:oy + tile_size, ox:ox + tile_size]
                tile = weight * _orient(crop, int(rng.integers(n_orient)), recipe.rotations)
                x0 = j * step
                if x0 + tile_size <= size:
                    strip[:, x0:x0 + tile_size] += tile
                else:
                    strip[:, x0:] += tile[:, :size - x0]
                    strip[:, :x0 + tile_size - size] += tile[:, size - x0:]
            num[rows] += strip
        # Variance-preserving blend: uncorrelated tiles keep the photo's contrast in overlaps.
        inv = (1.0 / np.sqrt(den_1d)).astype(np.float32)
        num *= inv[:, None]
        num *= inv[None, :] * np.float32(recipe.contrast)
        num += np.float32(recipe.mean if recipe.mean is not None else mean)
        # Start the canvas mid-tile rather than at a feather.
        canvas = np.roll(np.clip(num, 0, 255).astype(np.uint8), (-overlap // 2, -overlap // 2),
                         axis=(0, 1))
        return cls(canvas, metres_per_texel, name or recipe.photo)


def _orient(tile: NDArray, k: int, rotations: bool) -> NDArray:
    if rotations:
        tile = np.rot90(tile, k % 4)
        return tile[:, ::-1] if k >= 4 else tile
    return tile[:: (-1 if k & 1 else 1), :: (-1 if k & 2 else 1)]


def _pyramid(level0: NDArray[np.uint8]) -> list[NDArray[np.uint8]]:
    """Mip-map levels by exact 2×2 box averaging while both sides stay even."""
    levels = [np.ascontiguousarray(level0)]
    while all(s % 2 == 0 and s >= 8 for s in levels[-1].shape):
        prev = levels[-1]
        levels.append(cv2.resize(prev, (prev.shape[1] // 2, prev.shape[0] // 2),
                                 interpolation=cv2.INTER_AREA))
    return levels


def _load_photo(photo: str | Path) -> NDArray:
    path = Path(photo)
    if not path.is_file():
        path = data_path("textures", str(photo))
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise FileNotFoundError(f"texture photo unreadable: {path}")
    return img.astype(np.float64)


@functools.lru_cache(maxsize=3)
def load_texture(
    name: str, metres_per_texel: float, seed: int = 0, tiles: int = 24
) -> GroundTexture:
    """A named texture (see :data:`TEXTURES`) at ``metres_per_texel`` [m], cached."""
    if name not in TEXTURES:
        raise ValueError(f"unknown texture '{name}'; choose one of {sorted(TEXTURES)}")
    recipe = TEXTURES[name]
    return GroundTexture.from_photo(recipe.photo, metres_per_texel, tiles=tiles, seed=seed,
                                    recipe=recipe, name=name)
