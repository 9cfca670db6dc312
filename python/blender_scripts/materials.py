"""Procedural materials (bpy shader node trees): cardboard boxes with tape and a printed label,
and the support surfaces. Everything is driven by the draws in `sampling` and works in object
coordinates, i.e. the box frame (the box meshes are built at their true size, unscaled)."""

from __future__ import annotations

import bpy

from blender_scripts.sampling import BoxAppearance

Value = "float | bpy.types.NodeSocket"


def _by_id(sockets, identifier: str):
    """A node socket by identifier (names repeat across the typed variants of a Mix node)."""
    for s in sockets:
        if s.identifier == identifier:
            return s
    raise KeyError(identifier)


class Graph:
    """A thin helper over a shader node tree: numbers or sockets in, sockets out."""

    def __init__(self, tree: bpy.types.NodeTree):
        self.tree = tree
        self.nodes = tree.nodes
        self.links = tree.links

    def _feed(self, socket, value) -> None:
        if isinstance(value, bpy.types.NodeSocket):
            self.links.new(value, socket)
        elif value is not None:
            socket.default_value = value

    def node(self, kind: str, **props):
        n = self.nodes.new(kind)
        for k, v in props.items():
            setattr(n, k, v)
        return n

    def math(self, op: str, a, b=None, clamp: bool = False):
        n = self.node("ShaderNodeMath", operation=op, use_clamp=clamp)
        self._feed(n.inputs[0], a)
        if b is not None:
            self._feed(n.inputs[1], b)
        return n.outputs[0]

    def xyz(self, vector):
        n = self.node("ShaderNodeSeparateXYZ")
        self._feed(n.inputs[0], vector)
        return n.outputs["X"], n.outputs["Y"], n.outputs["Z"]

    def combine(self, x, y, z):
        n = self.node("ShaderNodeCombineXYZ")
        for s, v in zip(n.inputs, (x, y, z), strict=True):
            self._feed(s, v)
        return n.outputs[0]

    def noise(
        self,
        vector,
        scale: float,
        w: float = 0.0,
        detail: float = 2.0,
        roughness: float = 0.5,
        four_d: bool = True,
    ):
        n = self.node("ShaderNodeTexNoise", noise_dimensions="4D" if four_d else "3D")
        self._feed(n.inputs["Vector"], vector)
        if four_d:
            n.inputs["W"].default_value = w
        n.inputs["Scale"].default_value = scale
        n.inputs["Detail"].default_value = detail
        n.inputs["Roughness"].default_value = roughness
        return n.outputs["Fac"]

    def mix_color(self, factor, a, b):
        n = self.node("ShaderNodeMix", data_type="RGBA", clamp_factor=True)
        self._feed(_by_id(n.inputs, "Factor_Float"), factor)
        self._feed(_by_id(n.inputs, "A_Color"), a)
        self._feed(_by_id(n.inputs, "B_Color"), b)
        return _by_id(n.outputs, "Result_Color")

    def mix_float(self, factor, a, b):
        n = self.node("ShaderNodeMix", data_type="FLOAT", clamp_factor=True)
        self._feed(_by_id(n.inputs, "Factor_Float"), factor)
        self._feed(_by_id(n.inputs, "A_Float"), a)
        self._feed(_by_id(n.inputs, "B_Float"), b)
        return _by_id(n.outputs, "Result_Float")

    def scale_color(self, color, factor):
        n = self.node("ShaderNodeMix", data_type="RGBA", blend_type="MULTIPLY", clamp_factor=True)
        _by_id(n.inputs, "Factor_Float").default_value = 1.0
        self._feed(_by_id(n.inputs, "A_Color"), color)
        grey = self.combine(factor, factor, factor)
        self._feed(_by_id(n.inputs, "B_Color"), grey)
        return _by_id(n.outputs, "Result_Color")

    def band(self, coord, centre: float, half: float):
        """1 where |coord − centre| < half, else 0."""
        return self.math(
            "LESS_THAN", self.math("ABSOLUTE", self.math("SUBTRACT", coord, centre)), half
        )

    def both(self, a, b):
        return self.math("MULTIPLY", a, b)

    def principled(self, material, base_color, roughness, normal=None, specular: float = 0.5):
        bsdf = material.node_tree.nodes.get("Principled BSDF") or self.node(
            "ShaderNodeBsdfPrincipled"
        )
        self._feed(bsdf.inputs["Base Color"], base_color)
        self._feed(bsdf.inputs["Roughness"], roughness)
        bsdf.inputs["Specular IOR Level"].default_value = specular
        if normal is not None:
            self._feed(bsdf.inputs["Normal"], normal)
        return bsdf


def _rgba(rgb) -> tuple[float, float, float, float]:
    return (float(rgb[0]), float(rgb[1]), float(rgb[2]), 1.0)


def cardboard_material(
    name: str, size, base_color, roughness: float, look: BoxAppearance
) -> bpy.types.Material:
    """Cardboard: base colour modulated by low-frequency blotches and fine fibres;
    tape strips over the +z face and down two opposite sides; a printed label on +z."""
    mat = bpy.data.materials.new(name)
    g = Graph(mat.node_tree)
    coords = g.node("ShaderNodeTexCoord").outputs["Object"]
    x, y, z = g.xyz(coords)
    dz = float(size[2])
    ox, oy, oz = look.noise_offset

    # Cardboard colour: blotches (low frequency) and fibres (high frequency), both seeded.
    blotch = g.noise(coords, look.noise_scale, w=ox, detail=4.0, roughness=0.6)
    fibre = g.noise(coords, look.fibre_scale, w=oy, detail=1.0)
    shade = g.math(
        "ADD", 1.0, g.math("MULTIPLY", g.math("SUBTRACT", blotch, 0.5), 2.0 * look.color_variation)
    )
    shade = g.math("ADD", shade, g.math("MULTIPLY", g.math("SUBTRACT", fibre, 0.5), 0.12))
    color = g.scale_color(_rgba(base_color), shade)
    rough = float(roughness)
    rough_socket = None

    if look.tape is not None:
        t = look.tape
        across = y if t.axis == 0 else x  # strip runs along `axis`: select by the other coordinate
        on_strip = g.band(across, t.offset_m, 0.5 * t.width_m)
        high_enough = g.math("GREATER_THAN", z, 0.5 * dz - t.down_m)
        tape = g.math("MULTIPLY", g.both(on_strip, high_enough), t.opacity)
        color = g.mix_color(tape, color, _rgba(t.color))
        rough_socket = g.mix_float(tape, rough, t.roughness)

    if look.label is not None:
        lab = look.label
        cx, cy = lab.centre_m
        hu, hv = lab.half_m
        dxl, dyl = g.math("SUBTRACT", x, cx), g.math("SUBTRACT", y, cy)
        u, v = (dyl, g.math("MULTIPLY", dxl, -1.0)) if lab.rotated else (dxl, dyl)
        on_top = g.math("GREATER_THAN", z, 0.5 * dz - 1e-4)
        inside = g.both(g.both(g.band(u, 0.0, hu), g.band(v, 0.0, hv)), on_top)
        s = g.math("DIVIDE", g.math("ADD", u, hu), 2.0 * hu)  # 0..1 across the label
        tt = g.math("DIVIDE", g.math("ADD", v, hv), 2.0 * hv)
        in_s = g.band(s, 0.5, 0.42)
        # Barcode: crisp bars of random widths over the lower part of the label.
        bars = g.math(
            "GREATER_THAN",
            g.noise(
                g.combine(g.math("MULTIPLY", s, 9.0), lab.pattern_seed, 0.0), 4.0, w=oz, detail=0.0
            ),
            0.5,
        )
        barcode = g.both(g.both(bars, in_s), g.band(tt, 0.25, 0.17))
        # Text: five lines of "words" over the upper part.
        line = g.math("FLOOR", g.math("MULTIPLY", tt, 12.0))
        in_line = g.math("LESS_THAN", g.math("FRACT", g.math("MULTIPLY", tt, 12.0)), 0.55)
        words = g.math(
            "GREATER_THAN",
            g.noise(
                g.combine(
                    g.math("MULTIPLY", s, 3.0), g.math("MULTIPLY", line, 3.1), lab.pattern_seed
                ),
                3.0,
                w=oz,
                detail=0.0,
            ),
            0.42,
        )
        text = g.both(g.both(g.both(words, in_line), in_s), g.band(tt, 0.72, 0.2))
        ink = g.math("MAXIMUM", barcode, g.math("MULTIPLY", text, 0.8))
        paper = g.mix_color(ink, (0.82, 0.82, 0.78, 1.0), (0.02, 0.02, 0.02, 1.0))
        color = g.mix_color(inside, color, paper)
        rough_socket = g.mix_float(
            inside, rough_socket if rough_socket is not None else rough, 0.55
        )

    # No bump: at these resolutions it is invisible and costs ~20 % of a crop render.
    g.principled(mat, color, rough_socket if rough_socket is not None else rough, specular=0.3)
    return mat


def support_material(
    name: str, kind: str, appearance: dict, color_key: str = "color"
) -> bpy.types.Material:
    """Concrete-like floor, plastic bin or pine pallet boards: a base colour with seeded noise."""
    mat = bpy.data.materials.new(name)
    g = Graph(mat.node_tree)
    coords = g.node("ShaderNodeTexCoord").outputs["Object"]
    ox, oy, _ = appearance["noise_offset"]
    base = _rgba(appearance[color_key])
    if kind == "pallet" and color_key == "color":
        # Wood: grain stretched along x, boards separated by dark gaps along y.
        x, y, z = g.xyz(coords)
        grain = g.noise(g.combine(g.math("MULTIPLY", x, 0.08), y, z), 60.0, w=ox, detail=6.0)
        shade = g.math("ADD", 0.75, g.math("MULTIPLY", grain, 0.5))
        gap = g.math(
            "LESS_THAN",
            g.math("FRACT", g.math("MULTIPLY", g.math("ADD", y, 1000.0), 1.0 / 0.12)),
            0.06,
        )
        shade = g.math("MULTIPLY", shade, g.math("SUBTRACT", 1.0, g.math("MULTIPLY", gap, 0.7)))
        color = g.scale_color(base, shade)
    else:
        blotch = g.noise(coords, 3.0, w=ox, detail=6.0, roughness=0.65)
        speck = g.noise(coords, 80.0, w=oy, detail=2.0)
        shade = g.math(
            "ADD",
            0.8,
            g.math("ADD", g.math("MULTIPLY", blotch, 0.3), g.math("MULTIPLY", speck, 0.1)),
        )
        color = g.scale_color(base, shade)
    g.principled(mat, color, float(appearance["roughness"]), specular=0.4)
    return mat
