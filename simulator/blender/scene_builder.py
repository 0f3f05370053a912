"""Build Blender objects (meshes, materials, lights, camera, spotlight) from a bpy-free Scene."""

from __future__ import annotations

from dataclasses import dataclass, field

import bpy
import numpy as np

from simulator.lighting import SpotlightConfig
from simulator.scene_model import LightFixture, Material, MeshObject, Scene

#: OpenCV camera frame -> OpenGL/Blender camera frame (flip y and z).
CV_TO_GL = np.diag([1.0, -1.0, -1.0])


@dataclass
class BuiltScene:
    """Handles to what was built, so the renderer can switch between the two lighting modes.

    Attributes:
        camera: the camera object.
        spotlight: the camera-mounted spot light object.
        spot_local: (4, 4) pose of the spot light in the Blender camera frame (constant).
        fixtures: ground-truth light objects.
        emission_inputs: (socket, strength) pairs of the emission strengths to enable in the ground-truth render.
        meshes: every mesh object of the room (the uniform ground truth makes them cast no shadow).
    """

    camera: bpy.types.Object
    spotlight: bpy.types.Object
    spot_local: np.ndarray
    fixtures: list = field(default_factory=list)
    emission_inputs: list = field(default_factory=list)
    meshes: list = field(default_factory=list)


def reset_blender() -> None:
    """Start from an empty factory scene (the default one has a cube, a camera and a light)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)


def _image(path) -> bpy.types.Image:
    key = str(path)
    for img in bpy.data.images:
        if img.filepath == key:
            return img
    img = bpy.data.images.load(key, check_existing=True)
    img.colorspace_settings.name = "sRGB"
    return img


def build_material(mat: Material, built: BuiltScene, ceiling_glow: float = 0.0,
                   lambertian: bool = False) -> bpy.types.Material:
    """A Principled-BSDF material; emissive surfaces register their strength socket in ``built``.

    ``ceiling_glow`` > 0 makes the surface emit for indirect rays only (camera rays see the plain BSDF).
    ``lambertian`` turns the specular layer off and the metalness to 0: the BSDF is then exactly Blender's Lambertian
    Diffuse BSDF (same colour and texture).
    """
    bm = bpy.data.materials.new(mat.name)
    nodes, links = bm.node_tree.nodes, bm.node_tree.links
    nodes.clear()
    out = nodes.new("ShaderNodeOutputMaterial")
    bsdf = nodes.new("ShaderNodeBsdfPrincipled")
    color = (*mat.base_color, 1.0)
    bsdf.inputs["Base Color"].default_value = color
    bsdf.inputs["Roughness"].default_value = float(mat.roughness)
    bsdf.inputs["Metallic"].default_value = 0.0 if lambertian else float(mat.metallic)
    if lambertian:
        bsdf.inputs["Specular IOR Level"].default_value = 0.0
    if mat.texture is not None:
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = _image(mat.texture)
        tex.interpolation = "Linear"
        mix = nodes.new("ShaderNodeMix")
        mix.data_type = "RGBA"
        mix.blend_type = "MULTIPLY"
        mix.inputs["Factor"].default_value = 1.0
        links.new(tex.outputs["Color"], mix.inputs["A"])
        mix.inputs["B"].default_value = color
        links.new(mix.outputs["Result"], bsdf.inputs["Base Color"])
    surface = bsdf.outputs["BSDF"]
    if mat.emission > 0:
        bsdf.inputs["Emission Color"].default_value = (*mat.emission_color, 1.0)
        bsdf.inputs["Emission Strength"].default_value = 0.0
        built.emission_inputs.append((bsdf.inputs["Emission Strength"], float(mat.emission)))
    elif ceiling_glow > 0:
        glow = nodes.new("ShaderNodeEmission")
        glow.inputs["Color"].default_value = (1.0, 0.94, 0.86, 1.0)
        glow.inputs["Strength"].default_value = 0.0
        built.emission_inputs.append((glow.inputs["Strength"], float(ceiling_glow)))
        add = nodes.new("ShaderNodeAddShader")
        links.new(bsdf.outputs["BSDF"], add.inputs[0])
        links.new(glow.outputs["Emission"], add.inputs[1])
        path = nodes.new("ShaderNodeLightPath")
        mix = nodes.new("ShaderNodeMixShader")
        links.new(path.outputs["Is Camera Ray"], mix.inputs["Fac"])
        links.new(add.outputs["Shader"], mix.inputs[1])  # indirect rays: surface + glow
        links.new(bsdf.outputs["BSDF"], mix.inputs[2])  # camera rays: plain surface
        surface = mix.outputs["Shader"]
    links.new(surface, out.inputs["Surface"])
    return bm


def build_mesh(obj: MeshObject, material: bpy.types.Material) -> bpy.types.Object:
    """A Blender mesh object from world-space vertices/faces (+ UVs and custom normals when given)."""
    mesh = bpy.data.meshes.new(obj.name)
    verts = np.asarray(obj.vertices, dtype=np.float32)
    faces = np.asarray(obj.faces, dtype=np.int32)
    mesh.vertices.add(len(verts))
    mesh.vertices.foreach_set("co", verts.ravel())
    mesh.loops.add(faces.size)
    mesh.loops.foreach_set("vertex_index", faces.ravel())
    mesh.polygons.add(len(faces))
    mesh.polygons.foreach_set("loop_start", np.arange(0, faces.size, 3, dtype=np.int32))
    mesh.polygons.foreach_set("loop_total", np.full(len(faces), 3, dtype=np.int32))
    if obj.uvs is not None:
        layer = mesh.uv_layers.new(name="UVMap")
        layer.data.foreach_set("uv", np.asarray(obj.uvs, dtype=np.float32)[faces.ravel()].ravel())
    mesh.update(calc_edges=True)
    mesh.validate(clean_customdata=False)
    if obj.normals is not None and obj.source == "furniture":
        mesh.shade_smooth()
        mesh.normals_split_custom_set_from_vertices([tuple(n) for n in np.asarray(obj.normals, dtype=np.float32)])
    mesh.materials.append(material)
    ob = bpy.data.objects.new(obj.name, mesh)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def build_fixture(light: LightFixture) -> bpy.types.Object:
    """A Blender point or (downward) area light for the ground-truth render."""
    if light.kind == "area":
        data = bpy.data.lights.new(light.name, type="AREA")
        data.size = float(light.size)
    else:
        data = bpy.data.lights.new(light.name, type="POINT")
        data.shadow_soft_size = float(light.size)
    data.energy = float(light.power_w)
    data.color = tuple(light.color)
    ob = bpy.data.objects.new(light.name, data)
    ob.location = tuple(light.position)  # area lights face -z by default: down
    bpy.context.scene.collection.objects.link(ob)
    return ob


def spot_pose_in_blender_camera(spot: SpotlightConfig) -> np.ndarray:
    """(4, 4) pose of the Blender spot light in the Blender camera frame.

    The spotlight is specified in the OpenCV camera frame and shines along its +z; a Blender spot shines along its local
    -z and a Blender camera looks along -z with y up, so both frames are conjugated by ``CV_TO_GL``.
    """
    pose = np.eye(4)
    pose[:3, :3] = CV_TO_GL @ spot.rotation_matrix() @ CV_TO_GL
    pose[:3, 3] = CV_TO_GL @ np.asarray(spot.position_in_camera, dtype=np.float64)
    return pose


def spotlight_data(spot: SpotlightConfig) -> bpy.types.Light:
    """A Blender spot light with the camera-mounted spotlight's power, colour, cone, blend and emitter radius."""
    data = bpy.data.lights.new("spotlight", type="SPOT")
    data.energy = float(spot.power_w)
    data.color = tuple(spot.color)
    data.spot_size = float(np.deg2rad(spot.cone_angle_deg))
    data.spot_blend = float(spot.blend)
    data.shadow_soft_size = float(spot.radius_m)
    return data


def build_scene(scene: Scene, spot: SpotlightConfig, ceiling_glow: float, intrinsics,
                lambertian: bool = False) -> BuiltScene:
    """Create every object of ``scene`` plus the camera and its spotlight in the current (empty) Blender scene.

    ``lambertian``: every material as an ideal Lambertian reflector (see ``build_material``).
    """
    bscene = bpy.context.scene
    cam_data = bpy.data.cameras.new("camera")
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.sensor_width = 36.0
    cam_data.lens = float(intrinsics.fx) * 36.0 / float(intrinsics.width)
    cam_data.shift_x = (intrinsics.width / 2.0 - intrinsics.cx) / intrinsics.width
    cam_data.shift_y = (intrinsics.cy - intrinsics.height / 2.0) / intrinsics.width
    cam_data.clip_start = 0.01
    cam_data.clip_end = 1000.0
    camera = bpy.data.objects.new("camera", cam_data)
    bscene.collection.objects.link(camera)
    bscene.camera = camera

    spotlight = bpy.data.objects.new("spotlight", spotlight_data(spot))
    bscene.collection.objects.link(spotlight)

    built = BuiltScene(camera=camera, spotlight=spotlight, spot_local=spot_pose_in_blender_camera(spot))
    materials: dict[tuple, bpy.types.Material] = {}
    for obj in scene.objects:
        glow = ceiling_glow if obj.category.lower() == "ceiling" else 0.0
        key = (obj.material, glow)
        if key not in materials:
            materials[key] = build_material(obj.material, built, glow, lambertian)
        built.meshes.append(build_mesh(obj, materials[key]))
    built.fixtures = [build_fixture(light) for light in scene.lights]
    return built
