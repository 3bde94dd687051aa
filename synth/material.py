"""The Cycles skin material: the albedo image in the model's UV layout, roughness map,
subsurface scattering (bpy)."""
from __future__ import annotations

import bpy
import numpy as np


def float_image(name, values):
    """An in-memory, non-colour Blender image from (H, W) values in [0, 1] (top row first)."""
    height, width = values.shape
    image = bpy.data.images.new(name, width, height, alpha=False, float_buffer=True, is_data=True)
    image.colorspace_settings.name = "Non-Color"  # before the pixels: changing it reloads the buffer
    rgba = np.ones((height, width, 4), dtype=np.float32)
    rgba[..., :3] = values[::-1, :, None]  # Blender stores the bottom row first
    image.pixels.foreach_set(rgba.ravel())
    return image


SUBSURFACE_WEIGHT = 0.6
SPECULAR_LEVEL = 0.35   # Principled's Specular IOR Level at IOR 1.4: F0 0.019 (our lobe's level 0.24)


def skin_material(albedo_path, roughness, skin_tone, name="skin", subsurface=SUBSURFACE_WEIGHT,
                  specular_level=SPECULAR_LEVEL):
    """Principled skin shader reading the saved ground-truth albedo PNG (sRGB) and a roughness
    map (H, W); subsurface radius in metres, shorter for darker skin; `subsurface` its weight and
    `specular_level` its Specular IOR Level (both 0: a matte skin our renderer's Lambertian model
    draws alike)."""
    material = bpy.data.materials.new(name)
    nodes, links = material.node_tree.nodes, material.node_tree.links
    shader = nodes["Principled BSDF"]
    albedo = nodes.new("ShaderNodeTexImage")
    albedo.image = bpy.data.images.load(str(albedo_path), check_existing=False)
    albedo.image.colorspace_settings.name = "sRGB"
    albedo.interpolation = "Linear"
    rough = nodes.new("ShaderNodeTexImage")
    rough.image = float_image(f"{name}_roughness", roughness)
    rough.interpolation = "Linear"
    links.new(albedo.outputs["Color"], shader.inputs["Base Color"])
    links.new(rough.outputs["Color"], shader.inputs["Roughness"])
    shader.subsurface_method = "BURLEY"
    shader.inputs["Subsurface Weight"].default_value = subsurface
    shader.inputs["Subsurface Radius"].default_value = (1.0, 0.35, 0.2)
    shader.inputs["Subsurface Scale"].default_value = 0.002 * (1.0 - 0.5 * skin_tone)
    shader.inputs["Specular IOR Level"].default_value = specular_level
    shader.inputs["IOR"].default_value = 1.4
    return material


def flat_material(name, colour):
    """An emission-only material (used by the Cycles mask pass)."""
    material = bpy.data.materials.new(name)
    nodes, links = material.node_tree.nodes, material.node_tree.links
    nodes.remove(nodes["Principled BSDF"])
    emission = nodes.new("ShaderNodeEmission")
    emission.inputs["Color"].default_value = (*colour, 1.0)
    emission.inputs["Strength"].default_value = 1.0
    links.new(emission.outputs["Emission"], nodes["Material Output"].inputs["Surface"])
    return material
