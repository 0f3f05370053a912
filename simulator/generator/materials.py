"""Surface descriptions (texture recipe + PBR values) and the per-room-kind palettes.

A :class:`Surface` says how to make a texture and which roughness/metalness a surface has; the writers turn it into a
3D-FRONT ``material[]`` entry (architecture) or a 3D-FUTURE ``model.mtl`` (furniture). Textured surfaces carry their
colour in the texture and a white base colour, because readers multiply the two.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .textures import make_texture


@dataclass(frozen=True)
class Surface:
    """How one surface looks.

    Attributes:
        texture: texture kind (a key of ``textures.TEXTURE_KINDS``), or "" for an untextured colour.
        params: keyword arguments of the texture generator, as sorted ``(name, value)`` pairs (hashable).
        color: sRGB 0-255 colour used when ``texture`` is "" (and for the texture generator's ``color`` if absent).
        roughness: GGX roughness in [0, 1].
        metallic: metalness in [0, 1].
        uv_span: metres covered by one texture repeat on furniture, at least the model's largest side so that no
            model repeats its texture (architecture maps each surface once).
        aspect: texture width / height (wall textures are wide, everything else square).
    """

    texture: str
    params: tuple = ()
    color: tuple[int, int, int] = (255, 255, 255)
    roughness: float = 0.8
    metallic: float = 0.0
    uv_span: float = 1.0
    aspect: int = 1

    def __post_init__(self) -> None:
        if not (0.0 <= self.roughness <= 1.0 and 0.0 <= self.metallic <= 1.0):
            raise ValueError(f"roughness/metallic must lie in [0, 1], got {self.roughness}/{self.metallic}")

    def image(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """The texture image, (size, size * aspect, 3) uint8; raises if the surface is untextured."""
        if not self.texture:
            raise ValueError("an untextured surface has no image")
        return self.wide_image(rng, size, self.aspect)

    def wide_image(self, rng: np.random.Generator, size: int, aspect: int) -> np.ndarray:
        """The texture image ``aspect`` times wider than high, (size, size * aspect, 3) uint8 (only the kinds that
        take a ``width``: plaster, wood, tiles, terrazzo, carpet)."""
        if not self.texture:
            raise ValueError("an untextured surface has no image")
        kw = dict(self.params)
        if self.texture != "painting":
            kw.setdefault("color", self.color)
        if aspect != 1:
            kw["width"] = size * aspect
        return make_texture(self.texture, rng, size, **kw)


def surf(texture: str, roughness: float, metallic: float = 0.0, uv_span: float = 1.0, aspect: int = 1,
         color: tuple[int, int, int] = (255, 255, 255), **params) -> Surface:
    """Shorthand for :class:`Surface` with texture parameters as keywords."""
    return Surface(texture, tuple(sorted(params.items())), color, roughness, metallic, uv_span, aspect)


@dataclass(frozen=True)
class Palette:
    """The surfaces of one room kind.

    Attributes:
        floor, walls, ceiling, baseboard, door: architecture surfaces.
        furniture: surface per furniture type name (see ``furniture.FURNITURE_TYPES``); missing ones use ``default``.
        default: fallback furniture surface.
    """

    floor: Surface
    walls: Surface
    ceiling: Surface
    baseboard: Surface
    door: Surface
    default: Surface
    furniture: dict[str, Surface] = field(default_factory=dict)

    def for_furniture(self, type_name: str) -> Surface:
        """The surface of a furniture type in this room."""
        return self.furniture.get(type_name, self.default)

    def all_surfaces(self) -> list[Surface]:
        """Every surface of the palette (architecture first)."""
        return [self.floor, self.walls, self.ceiling, self.baseboard, self.door, self.default,
                *self.furniture.values()]


_LAMP = surf("lamp_diffuser", 0.85, color=(250, 244, 232))
_PAINTING = surf("painting", 0.85)

PALETTES: dict[str, Palette] = {
    # Fully diffuse: every roughness >= 0.8 and metalness 0 (a Lambertian reference room).
    "bedroom": Palette(
        floor=surf("carpet", 0.95, color=(150, 128, 110)),
        walls=surf("plaster", 0.9, aspect=6, color=(214, 206, 188)),
        ceiling=surf("plaster", 0.9, color=(236, 234, 228)),
        baseboard=surf("wood", 0.85, color=(235, 232, 225)),
        door=surf("wood", 0.85, color=(160, 115, 75)),
        default=surf("wood", 0.85, uv_span=1.2, color=(165, 120, 80)),
        furniture={
            "bed": surf("fabric", 0.95, uv_span=1.0, color=(95, 115, 150), accent=(215, 190, 130)),
            "wardrobe": surf("wood", 0.85, uv_span=2.0, color=(200, 170, 130)),
            "armchair": surf("fabric", 0.95, uv_span=0.8, color=(150, 80, 70), accent=(230, 220, 200)),
            "painting": _PAINTING, "ceiling_lamp": _LAMP, "floor_lamp": _LAMP, "desk_lamp": _LAMP,
            "wall_lamp": _LAMP,
        },
    ),
    "living_room": Palette(
        floor=surf("wood", 0.18, color=(175, 125, 80), planks=18),
        walls=surf("plaster", 0.85, aspect=6, color=(208, 214, 210)),
        ceiling=surf("plaster", 0.9, color=(238, 238, 234)),
        baseboard=surf("wood", 0.5, color=(240, 240, 236)),
        door=surf("wood", 0.6, color=(120, 85, 55)),
        default=surf("wood", 0.55, uv_span=1.2, color=(120, 80, 50)),
        furniture={
            "sofa": surf("fabric", 0.9, uv_span=1.0, color=(100, 112, 98), accent=(235, 205, 150)),
            "armchair": surf("fabric", 0.9, uv_span=0.8, color=(170, 130, 90), accent=(60, 60, 70)),
            "coffee_table": surf("tiles", 0.08, uv_span=1.0, color=(225, 222, 215), count=3),
            "tv_stand": surf("wood", 0.2, uv_span=1.5, color=(60, 45, 35)),
            "bookcase": surf("wood", 0.6, uv_span=1.5, color=(180, 140, 95)),
            "painting": _PAINTING, "ceiling_lamp": _LAMP, "floor_lamp": _LAMP, "pendant_lamp": _LAMP,
            "wall_lamp": _LAMP,
        },
    ),
    "office": Palette(
        floor=surf("carpet", 0.9, color=(90, 95, 105)),
        walls=surf("plaster", 0.8, aspect=6, color=(225, 225, 218)),
        ceiling=surf("plaster", 0.9, color=(240, 240, 238)),
        baseboard=surf("brushed_metal", 0.35, metallic=1.0, color=(150, 152, 155)),
        door=surf("wood", 0.5, color=(190, 160, 120)),
        default=surf("wood", 0.5, uv_span=1.2, color=(185, 150, 110)),
        furniture={
            "desk": surf("wood", 0.2, uv_span=1.6, color=(150, 105, 70)),
            "office_chair": surf("fabric", 0.85, uv_span=0.6, color=(50, 55, 65), accent=(120, 130, 150)),
            "bookcase": surf("wood", 0.6, uv_span=1.5, color=(110, 75, 50)),
            "filing_cabinet": surf("brushed_metal", 0.3, metallic=1.0, uv_span=0.8, color=(170, 172, 176)),
            "metal_shelf": surf("brushed_metal", 0.25, metallic=1.0, uv_span=1.0, color=(185, 185, 188)),
            "painting": _PAINTING, "ceiling_lamp": _LAMP, "desk_lamp": _LAMP, "floor_lamp": _LAMP,
        },
    ),
    # Strongly metallic / glossy.
    "storage_room": Palette(
        floor=surf("terrazzo", 0.1, color=(150, 152, 150)),
        walls=surf("plaster", 0.3, aspect=6, color=(200, 205, 200)),
        ceiling=surf("plaster", 0.8, color=(230, 230, 228)),
        baseboard=surf("brushed_metal", 0.2, metallic=1.0, color=(160, 162, 165)),
        door=surf("brushed_metal", 0.2, metallic=1.0, color=(170, 172, 175)),
        default=surf("brushed_metal", 0.15, metallic=1.0, uv_span=1.0, color=(190, 190, 192)),
        furniture={
            "metal_shelf": surf("brushed_metal", 0.2, metallic=1.0, uv_span=1.0, color=(195, 196, 198)),
            "steel_cabinet": surf("brushed_metal", 0.1, metallic=1.0, uv_span=1.2, color=(175, 178, 182)),
            "tool_chest": surf("brushed_metal", 0.15, metallic=1.0, uv_span=0.8, color=(200, 60, 50)),
            "workbench": surf("wood", 0.15, uv_span=1.5, color=(150, 110, 70)),
            "painting": surf("painting", 0.1),
            "ceiling_lamp": _LAMP, "wall_lamp": _LAMP, "floor_lamp": _LAMP,
        },
    ),
    # White and matte everywhere (linear albedo about 0.75-0.8): strong interreflection.
    "white_room": Palette(
        floor=surf("tiles", 0.8, color=(235, 232, 226), count=5),
        walls=surf("plaster", 0.9, aspect=6, color=(232, 231, 226)),
        ceiling=surf("plaster", 0.9, color=(236, 236, 233)),
        baseboard=surf("wood", 0.8, color=(240, 238, 232)),
        door=surf("wood", 0.8, color=(236, 233, 226)),
        default=surf("wood", 0.8, uv_span=1.2, color=(238, 235, 228)),
        furniture={
            "armchair": surf("fabric", 0.95, uv_span=0.8, color=(240, 238, 232), accent=(225, 222, 214)),
            "painting": _PAINTING, "ceiling_lamp": _LAMP, "floor_lamp": _LAMP,
        },
    ),
    "corridor": Palette(
        floor=surf("tiles", 0.12, color=(205, 200, 190), count=6),
        walls=surf("plaster", 0.7, aspect=6, color=(222, 210, 190)),
        ceiling=surf("plaster", 0.9, color=(240, 238, 232)),
        baseboard=surf("wood", 0.4, color=(90, 65, 45)),
        door=surf("wood", 0.5, color=(130, 90, 60)),
        default=surf("wood", 0.45, uv_span=1.2, color=(140, 100, 65)),
        furniture={
            "console_table": surf("wood", 0.2, uv_span=1.2, color=(80, 55, 40)),
            "bench": surf("brushed_metal", 0.2, metallic=1.0, uv_span=1.0, color=(180, 182, 185)),
            "shoe_cabinet": surf("wood", 0.5, uv_span=1.0, color=(210, 200, 185)),
            "painting": _PAINTING, "ceiling_lamp": _LAMP, "wall_lamp": _LAMP, "floor_lamp": _LAMP,
        },
    ),
}
"""Surfaces per room kind."""
