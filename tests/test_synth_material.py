"""The Cycles skin of synth/material.py against the analytic case: a flat slab under a uniform
white world of radiance 1 sends back exactly its base colour (in linear light) where the skin is
matte (no subsurface weight, no specular level), the case our renderer's Lambertian model draws;
the default skin's sheen adds white light, the more the darker the skin (what the fitted albedo of
a Cycles clip takes in where the fit's sheen falls short: docs/fidelity.md)."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytestmark = pytest.mark.blender

from pipeline.formats.colour_model import srgb_to_linear  # noqa: E402
from synth.material import SPECULAR_LEVEL, SUBSURFACE_WEIGHT, skin_material  # noqa: E402

TONES = {"dark": (0.33, 0.21, 0.15), "light": (0.85, 0.66, 0.56)}   # sRGB base colours, a back and a palm


def rendered_over_base(tmp_path, subsurface, specular_level):
    """{tone: (3,) the rendered linear colour over the base colour} of two slabs seen from above."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 64
    scene.cycles.use_denoising = False
    scene.view_settings.view_transform = "Standard"
    scene.render.resolution_x, scene.render.resolution_y = 40, 20
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.world = bpy.data.worlds.new("white")
    background = scene.world.node_tree.nodes["Background"]
    background.inputs["Color"].default_value = (1, 1, 1, 1)
    background.inputs["Strength"].default_value = 1.0
    for index, (name, colour) in enumerate(TONES.items()):
        path = tmp_path / f"{name}.png"
        image = bpy.data.images.new(name, 4, 4)
        image.pixels.foreach_set(np.tile([*colour, 1.0], 16).astype(np.float32))
        image.filepath_raw, image.file_format = str(path), "PNG"
        image.save()
        bpy.ops.mesh.primitive_cube_add(size=1, location=(-0.025 + 0.05 * index, 0, -0.005), scale=(0.05, 0.05, 0.01))
        material = skin_material(path, np.full((4, 4), 0.5, np.float32), 0.5, name=name, subsurface=subsurface,
                                 specular_level=specular_level)
        bpy.context.object.data.materials.append(material)
    bpy.ops.object.camera_add(location=(0, 0, 0.5))
    scene.camera = bpy.context.object
    scene.camera.data.type = "ORTHO"
    scene.camera.data.ortho_scale = 0.1
    scene.render.filepath = str(tmp_path / "slabs.exr")
    bpy.ops.render.render(write_still=True)
    result = bpy.data.images.load(str(tmp_path / "slabs.exr"))
    pixels = np.array(result.pixels[:]).reshape(20, 40, 4)[..., :3]
    ratios = {}
    for index, (name, colour) in enumerate(TONES.items()):
        patch = pixels[5:15, 5 + 20 * index:15 + 20 * index].reshape(-1, 3).mean(0)
        base = srgb_to_linear(np.asarray(colour, dtype=np.float64))
        ratios[name] = patch / base
    return ratios


def test_matte_skin_renders_its_base_colour(tmp_path):
    ratios = rendered_over_base(tmp_path, subsurface=0.0, specular_level=0.0)
    for name in TONES:
        np.testing.assert_allclose(ratios[name], 1.0, atol=0.02)


def test_the_default_sheen_lightens_dark_skin_most(tmp_path):
    ratios = rendered_over_base(tmp_path, subsurface=SUBSURFACE_WEIGHT, specular_level=SPECULAR_LEVEL)
    assert np.all(ratios["dark"] > ratios["light"] + 0.05)          # the white sheen, over a darker colour
    assert ratios["dark"][2] > ratios["dark"][0] + 0.2               # most on the darkest channel, blue
    np.testing.assert_allclose(ratios["light"], 1.0, atol=0.08)
