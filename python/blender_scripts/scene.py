"""The Blender scene (bpy): support, boxes, lights, camera; Cycles CPU renders read back in memory.

One `BlenderScene` per process: it resets Blender once, then `build()` replaces the scene content
and `render()` can be called many times with other cameras, lights, box poses, sample counts or
crop regions; Cycles keeps its scene data between renders (`use_persistent_data`).

Read-back: Blender writes the render (a multi-part EXR with Combined, Depth and Object Index, and
the colour-managed PNG) into anonymous in-memory files (`memfd_create`) that are read straight
back: no temporary files on disk, no compositor.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass

import bpy
import mathutils
import numpy as np

from blender_scripts import geometry as geo
from blender_scripts.exr import read_exr
from blender_scripts.materials import cardboard_material, support_material
from blender_scripts.recipe import SupportSpec

# Same support geometry as the physics (python/drake_scenes/plant.py: support_boxes), from the
# dataset contract (rust/data/src/support.rs, via schema.json): the ground's top is z = 0; bin walls
# stand on it with their inner faces on the support region's edges; a pallet is a slab of exactly
# the support region, PALLET_HEIGHT_M high, standing on the ground.
from boxpose_io import BIN_WALL_THICKNESS_M, PALLET_HEIGHT_M

# Background pixels get this depth from Cycles (no surface); stored as 0.
_NO_SURFACE = 1e9
_FLOOR_HALF_EXTENT_M = 20.0


@dataclass
class RenderOutput:
    rgb_png: bytes  # 8-bit sRGB PNG through the scene's colour management
    depth: np.ndarray  # float32 (H, W), planar z in metres, 0 = no surface
    index: np.ndarray  # uint16 (H, W), object pass index = object_id + 1, 0 = support / none
    seconds: float  # wall time of the render and the read-back


class BlenderError(RuntimeError):
    pass


def _box_mesh(name: str, size) -> bpy.types.Mesh:
    """A box mesh in its own frame (centre at the origin), outward-facing quads."""
    corners = geo.box_corners(size)
    faces = []
    for axis in range(3):
        for sign in (0, 1):
            quad = [i for i in range(8) if (i >> axis) & 1 == sign]
            # order the 4 corners around the face, then make the normal point outwards
            a, b = [k for k in range(3) if k != axis]
            centre = corners[quad].mean(axis=0)
            quad.sort(
                key=lambda i: math.atan2(corners[i][b] - centre[b], corners[i][a] - centre[a])
            )
            normal = np.cross(
                corners[quad[1]] - corners[quad[0]], corners[quad[2]] - corners[quad[0]]
            )
            outward = np.zeros(3)
            outward[axis] = 1.0 if sign else -1.0
            if np.dot(normal, outward) < 0:
                quad.reverse()
            faces.append(quad)
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([tuple(c) for c in corners], [], faces)
    mesh.update()
    return mesh


def _matrix(m: np.ndarray) -> mathutils.Matrix:
    return mathutils.Matrix([list(map(float, row)) for row in np.asarray(m)])


def _read_fd(fd: int) -> bytes:
    return os.pread(fd, os.fstat(fd).st_size, 0)


# Ancillary PNG chunks that Blender fills with the wall clock (the date, render times): left in,
# two renders of one scene differ in their bytes though not in a pixel.
_CLOCK_CHUNKS = (b"tEXt", b"zTXt", b"iTXt", b"tIME")


def without_text_chunks(png: bytes) -> bytes:
    """`png` without its text and time chunks (each chunk carries its own CRC, so the rest
    stays valid): the same pixels give the same bytes."""
    out, i = [png[:8]], 8
    while i < len(png):
        length = int.from_bytes(png[i : i + 4], "big")
        end = i + 12 + length  # length, type, data, CRC
        if png[i + 4 : i + 8] not in _CLOCK_CHUNKS:
            out.append(png[i:end])
        i = end
    return b"".join(out)


class BlenderScene:
    def __init__(self, threads: int = 0):
        bpy.ops.wm.read_factory_settings(use_empty=True)
        self.scene = bpy.context.scene
        self.view_layer = self.scene.view_layers[0]
        self.threads = threads
        self._exr_fd = os.memfd_create("boxpose-render-exr")
        self._png_fd = os.memfd_create("boxpose-render-png")
        self.boxes: dict[int, bpy.types.Object] = {}
        self._object_ids: dict[str, int] = {}
        self.camera_object: bpy.types.Object | None = None
        self.lights: list[bpy.types.Object] = []
        self._configure()

    # -- static settings ------------------------------------------------------------------

    def _configure(self) -> None:
        s = self.scene
        s.render.engine = "CYCLES"
        s.cycles.device = "CPU"
        s.render.use_persistent_data = True
        s.render.film_transparent = False
        s.render.resolution_percentage = 100
        s.render.pixel_aspect_x = s.render.pixel_aspect_y = 1.0
        s.render.threads_mode = "FIXED" if self.threads > 0 else "AUTO"
        if self.threads > 0:
            s.render.threads = self.threads
        s.cycles.use_adaptive_sampling = False
        s.cycles.use_animated_seed = False
        s.cycles.denoiser = "OPENIMAGEDENOISE"
        # BALANCED: about half the denoising time of HIGH, no visible loss on these scenes.
        s.cycles.denoising_quality = "BALANCED"
        s.cycles.denoising_prefilter = "ACCURATE"
        s.cycles.caustics_reflective = s.cycles.caustics_refractive = False
        s.display_settings.display_device = "sRGB"
        self.view_layer.use_pass_z = True
        self.view_layer.use_pass_object_index = True
        world = bpy.data.worlds.new("World")
        s.world = world

    def settings(self) -> dict:
        """The static part of the render settings, for `frames.render_settings`."""
        c = self.scene.cycles
        return {
            "engine": "CYCLES",
            "device": "CPU",
            "adaptive_sampling": False,
            "denoiser": "OPENIMAGEDENOISE",
            "denoising_input_passes": c.denoising_input_passes,
            "denoising_prefilter": c.denoising_prefilter,
            "denoising_quality": c.denoising_quality,
            "pixel_filter": c.pixel_filter_type,
            "filter_width_px": c.filter_width,
            "diffuse_bounces": c.diffuse_bounces,
            "glossy_bounces": c.glossy_bounces,
            "display_device": self.scene.display_settings.display_device,
        }

    # -- scene content --------------------------------------------------------------------

    def clear(self) -> None:
        for collection in (
            bpy.data.objects,
            bpy.data.meshes,
            bpy.data.materials,
            bpy.data.lights,
            bpy.data.cameras,
        ):
            if len(collection):
                bpy.data.batch_remove(list(collection))
        self.boxes.clear()
        self._object_ids.clear()
        self.camera_object = None
        self.lights = []

    def _link(self, obj: bpy.types.Object) -> bpy.types.Object:
        self.scene.collection.objects.link(obj)
        return obj

    def _slab(self, name: str, lo, hi, material) -> bpy.types.Object:
        lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
        obj = bpy.data.objects.new(name, _box_mesh(name, hi - lo))
        obj.location = tuple((lo + hi) / 2)
        obj.data.materials.append(material)
        obj.pass_index = 0
        self._object_ids[obj.name] = -1
        return self._link(obj)

    def build(self, support: SupportSpec, support_look: dict, boxes: list[dict]) -> None:
        """Replaces the scene: the support (ground top at world z = 0) and the boxes.
        `boxes`: dicts with object_id, size, world_box (4×4), base_color, roughness, appearance."""
        self.clear()
        h = _FLOOR_HALF_EXTENT_M
        hx, hy = support.half_extent_m
        if support.kind == "floor":
            self._slab(
                "support_floor",
                (-h, -h, -0.05),
                (h, h, 0.0),
                support_material("floor", "floor", support_look),
            )
        elif support.kind == "bin":
            t, wall = BIN_WALL_THICKNESS_M, support.wall_height_m
            mat = support_material("bin", "bin", support_look)
            self._slab(
                "support_floor",
                (-h, -h, -0.05),
                (h, h, 0.0),
                support_material("ground", "floor", support_look, "floor_color"),
            )
            self._slab("support_wall_-x", (-hx - t, -hy - t, 0.0), (-hx, hy + t, wall), mat)
            self._slab("support_wall_+x", (hx, -hy - t, 0.0), (hx + t, hy + t, wall), mat)
            self._slab("support_wall_-y", (-hx, -hy - t, 0.0), (hx, -hy, wall), mat)
            self._slab("support_wall_+y", (-hx, hy, 0.0), (hx, hy + t, wall), mat)
        elif support.kind == "pallet":
            ph = PALLET_HEIGHT_M
            self._slab(
                "support_floor",
                (-h, -h, -0.05),
                (h, h, 0.0),
                support_material("ground", "floor", support_look, "floor_color"),
            )
            self._slab(
                "support_pallet",
                (-hx, -hy, 0.0),
                (hx, hy, ph),
                support_material("pallet", "pallet", support_look),
            )
        else:
            raise BlenderError(f"unknown support kind '{support.kind}' (floor, bin or pallet)")
        for box in boxes:
            oid = int(box["object_id"])
            name = f"box_{oid:03d}"
            obj = bpy.data.objects.new(name, _box_mesh(name, box["size"]))
            obj.data.materials.append(
                cardboard_material(
                    name, box["size"], box["base_color"], box["roughness"], box["appearance"]
                )
            )
            obj.pass_index = oid + 1
            obj.matrix_world = _matrix(box["world_box"])
            self.boxes[oid] = self._link(obj)
            self._object_ids[obj.name] = oid
        cam = bpy.data.cameras.new("camera")
        cam.sensor_fit = "HORIZONTAL"
        cam.sensor_width = 36.0
        cam.shift_x = cam.shift_y = 0.0
        cam.clip_start, cam.clip_end = 0.01, 100.0
        self.camera_object = self._link(bpy.data.objects.new("camera", cam))
        self.scene.camera = self.camera_object

    def set_box_pose(self, object_id: int, world_box: np.ndarray) -> None:
        self.boxes[object_id].matrix_world = _matrix(world_box)

    def set_camera(self, camera: geo.Camera) -> None:
        """Places Blender's camera so that its image is exactly the pinhole `camera` (fx = fy,
        principal point at the image centre; other intrinsics cannot be matched without shift)."""
        if abs(camera.fx - camera.fy) > 1e-9 * camera.fx:
            raise BlenderError("Blender cameras need square pixels (fx = fy)")
        r = self.scene.render
        r.resolution_x, r.resolution_y = camera.width, camera.height
        self.camera_object.data.lens = geo.blender_lens(
            camera, self.camera_object.data.sensor_width
        )
        self.camera_object.matrix_world = _matrix(geo.blender_camera_matrix(camera.world_camera))

    def set_lighting(self, lighting: dict) -> None:
        for obj in self.lights:
            light = obj.data
            bpy.data.objects.remove(obj)
            bpy.data.lights.remove(light)
        self.lights = []
        sun = lighting["sun"]
        data = bpy.data.lights.new("sun", type="SUN")
        data.energy = sun["strength"]
        data.angle = math.radians(sun["angle_deg"])
        obj = bpy.data.objects.new("sun", data)
        obj.matrix_world = _matrix(_aim(np.zeros(3), -np.asarray(sun["direction"])))
        self.lights.append(self._link(obj))
        for k, area in enumerate(lighting["area"]):
            data = bpy.data.lights.new(f"area_{k}", type="AREA")
            data.energy = area["power_w"]
            data.size = area["size_m"]
            data.color = area["color"]
            obj = bpy.data.objects.new(f"area_{k}", data)
            loc = np.asarray(area["location_m"])
            obj.matrix_world = _matrix(_aim(loc, np.asarray(area["target_m"]) - loc))
            self.lights.append(self._link(obj))
        world = lighting["world"]
        bg = self.scene.world.node_tree.nodes.get(
            "Background"
        ) or self.scene.world.node_tree.nodes.new("ShaderNodeBackground")
        bg.inputs["Color"].default_value = (*world["color"], 1.0)
        bg.inputs["Strength"].default_value = world["strength"]
        out = self.scene.world.node_tree.nodes.get("World Output")
        if out is not None and not out.inputs["Surface"].is_linked:
            self.scene.world.node_tree.links.new(bg.outputs["Background"], out.inputs["Surface"])

    # -- rendering ------------------------------------------------------------------------

    def render(
        self,
        samples: int,
        denoise: bool,
        seed: int,
        max_bounces: int,
        view_transform: str,
        exposure: float,
        crop: tuple[int, int, int, int] | None = None,
    ) -> RenderOutput:
        """Renders the current camera; `crop` = (x0, y0, x1, y1), max exclusive, renders only
        that region (Cycles border render, cropped output)."""
        s, c, r = self.scene, self.scene.cycles, self.scene.render
        c.samples = int(samples)
        c.use_denoising = bool(denoise)
        c.seed = int(seed)
        c.max_bounces = int(max_bounces)
        c.diffuse_bounces = min(int(max_bounces), 4)
        c.glossy_bounces = min(int(max_bounces), 2)
        c.transmission_bounces = c.volume_bounces = 0
        c.transparent_max_bounces = 2
        s.view_settings.view_transform = view_transform
        s.view_settings.look = "None"
        s.view_settings.exposure = float(exposure)
        s.view_settings.gamma = 1.0
        w, h = r.resolution_x, r.resolution_y
        if crop is None:
            r.use_border = False
            x0, y0, x1, y1 = 0, 0, w, h
        else:
            x0, y0, x1, y1 = (int(v) for v in crop)
            if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
                raise BlenderError(f"crop {crop} is not a non-empty region of the {w}×{h} image")
            r.use_border = True
            r.use_crop_to_border = True

            # Blender's border is normalized with y up, stored in float32, and border × size is
            # truncated to whole pixels: 250 / 480 comes back as 249.99998 → 249, a row too many.
            # A thousandth of a pixel inwards lands every edge on its pixel, truncated or rounded.
            def edge(pixels: int, size: int) -> float:
                return min((pixels + 1e-3) / size, 1.0)

            r.border_min_x, r.border_max_x = edge(x0, w), edge(x1, w)
            r.border_min_y, r.border_max_y = edge(h - y1, h), edge(h - y0, h)
        start = time.perf_counter()
        bpy.ops.render.render(write_still=False)
        result = bpy.data.images["Render Result"]
        im = r.image_settings
        im.media_type = "MULTI_LAYER_IMAGE"
        im.file_format = "OPEN_EXR_MULTILAYER"
        im.color_depth = "32"
        im.exr_codec = "NONE"
        result.save_render(filepath=f"/proc/self/fd/{self._exr_fd}", scene=s)
        channels = read_exr(_read_fd(self._exr_fd))
        im.media_type = "IMAGE"
        im.file_format = "PNG"
        im.color_mode = "RGB"
        im.color_depth = "8"
        im.compression = 15
        result.save_render(filepath=f"/proc/self/fd/{self._png_fd}", scene=s)
        rgb_png = without_text_chunks(_read_fd(self._png_fd))
        seconds = time.perf_counter() - start
        try:
            depth = channels["ViewLayer.Depth.Z"]
            index = channels["ViewLayer.Object Index.X"]
        except KeyError as e:
            raise BlenderError(f"render result lacks pass {e}; found {sorted(channels)}") from e
        if depth.shape != (y1 - y0, x1 - x0):
            raise BlenderError(
                f"render is {depth.shape[1]}×{depth.shape[0]}, expected {x1 - x0}×{y1 - y0}"
            )
        # EXR rows run top to bottom like our images.
        depth = np.where(depth < _NO_SURFACE, depth, 0.0).astype(np.float32)
        index = np.rint(index).astype(np.uint16)
        return RenderOutput(rgb_png, depth, index, seconds)

    def ray_cast(self, origin: np.ndarray, direction: np.ndarray, distance: float):
        """The first surface along a ray: (location, normal, object_id or −1), or None."""
        depsgraph = bpy.context.evaluated_depsgraph_get()
        hit, location, normal, _index, obj, _m = self.scene.ray_cast(
            depsgraph,
            mathutils.Vector(origin.tolist()),
            mathutils.Vector(direction.tolist()),
            distance=float(distance),
        )
        if not hit:
            return None
        oid = self._object_ids.get(obj.original.name if obj is not None else "", -1)
        return np.array(location), np.array(normal), oid

    def update(self) -> None:
        """Brings the dependency graph up to date after moving objects (before ray casts)."""
        self.view_layer.update()


def _aim(location: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """4×4 pose of a light at `location` whose local −z axis points along `direction`."""
    z = -np.asarray(direction, dtype=float)
    z /= np.linalg.norm(z)
    helper = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.99 else np.array([1.0, 0.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, location
    return m
