"""Textures that travel with the .blend (Blender, the bpy module, as the reference): `harp blend`
with a relative avatar path, from any working directory, writes image paths relative to the
.blend's own folder; `--pack` and Export's packing put the images inside it. Every check
reopens the file elsewhere and reloads each image: it must have pixels (has_data), at the size
the clip and the fit were made at (tests/blender_fixture.py)."""
import os
import shutil

import pytest

bpy = pytest.importorskip("bpy")

from blender_fixture import FRAME_SIZE, TEXTURE_SIZE  # noqa: E402
from harp_addon import actions  # noqa: E402
from pipeline.cli import main  # noqa: E402

pytestmark = pytest.mark.blender
SIZES = {"albedo.png": (TEXTURE_SIZE, TEXTURE_SIZE), "normal.png": (TEXTURE_SIZE, TEXTURE_SIZE),
         "000000.png": (FRAME_SIZE, FRAME_SIZE)}     # the albedo, the normal map, the footage's first frame


@pytest.fixture
def project(prepared_avatar, tmp_path):
    """A project folder as the README has it: the demo's avatar and its clip in harp_demo/."""
    folder = tmp_path / "project"
    shutil.copytree(prepared_avatar.avatar, folder / "harp_demo" / "avatar")
    shutil.copytree(prepared_avatar.clip, folder / "harp_demo" / "clip")
    return folder


def images_in(blend, cwd):
    """Open `blend` from the working directory `cwd`; {name: (size, packed)} of its file images
    that hold pixels after a reload, None for those that do not."""
    previous = os.getcwd()
    os.chdir(cwd)
    try:
        bpy.ops.wm.open_mainfile(filepath=str(blend))
        found = {}
        for image in bpy.data.images:
            if image.source in ("FILE", "SEQUENCE"):
                image.reload()
                size = tuple(image.size)          # reading the size loads the pixels
                found[image.name] = (size, image.packed_file is not None) if image.has_data else None
        return found
    finally:
        os.chdir(previous)


def expected(packed):
    return {name: (size, packed) for name, size in SIZES.items()}


def harp_blend(cwd, *arguments):
    previous = os.getcwd()
    os.chdir(cwd)
    try:
        assert main(["blend", *arguments]) == 0
    finally:
        os.chdir(previous)


@pytest.mark.parametrize("where, avatar, out", [
    (".", "harp_demo/avatar", "scene.blend"),                       # the README's command
    ("work", "../harp_demo/avatar", "../renders/scene.blend"),
    ("work", "{project}/harp_demo/avatar", "scene.blend"),
])
def test_image_paths_are_relative_to_the_blend(project, tmp_path, where, avatar, out):
    cwd = project / where
    cwd.mkdir(exist_ok=True)
    harp_blend(cwd, avatar.format(project=project), "--out", out, "--sequence", "{}/harp_demo/clip".format(
        os.path.relpath(project, cwd)))
    blend = (cwd / out).resolve()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    assert images_in(blend, elsewhere) == expected(packed=False)
    assert all(image.filepath.startswith("//") for image in bpy.data.images if image.source != "VIEWER")
    # the whole project moved: the paths, relative to the .blend, still find the images
    moved = tmp_path / "moved"
    project.rename(moved)
    assert images_in(moved / blend.relative_to(project), elsewhere) == expected(packed=False)
    assert all(image.filepath_from_user().startswith(str(moved)) for image in bpy.data.images
               if image.source in ("FILE", "SEQUENCE"))


def test_readme_command_without_sequence_finds_the_recorded_footage(project, prepared_avatar, tmp_path):
    harp_blend(project, "harp_demo/avatar", "--out", "scene.blend")
    assert images_in(project / "scene.blend", tmp_path) == expected(packed=False)
    footage = bpy.data.images["000000.png"].filepath_from_user()
    assert os.path.samefile(footage, prepared_avatar.clip / "rgb" / "000000.png")


def test_a_packed_blend_travels_alone(project, tmp_path):
    harp_blend(project, "harp_demo/avatar", "--out", "scene.blend", "--pack", "--sequence", "harp_demo/clip")
    alone = tmp_path / "alone"
    alone.mkdir()
    shutil.move(project / "scene.blend", alone / "moved.blend")
    shutil.rmtree(project)                     # the avatar and the footage are gone
    assert images_in(alone / "moved.blend", tmp_path) == expected(packed=True)


def test_export_packs_for_the_copy_only(project, tmp_path, empty_scene):
    bound = actions.bind(project / "harp_demo" / "avatar", project / "harp_demo" / "clip")
    actions.export(bound, blend=tmp_path / "out" / "hand.blend", pack=True)
    assert [image.name for image in bpy.data.images if image.packed_file] == []    # the open file as it was
    shutil.rmtree(project)
    assert images_in(tmp_path / "out" / "hand.blend", tmp_path) == expected(packed=True)


def test_bind_pack_option_and_the_skin_material(project, tmp_path, empty_scene):
    bound = actions.bind(project / "harp_demo" / "avatar", project / "harp_demo" / "clip", pack=True)
    assert {image.name for image in bpy.data.images if image.packed_file} == set(SIZES)
    links = {(link.from_node.image.name if link.from_node.bl_idname == "ShaderNodeTexImage" else
              link.from_node.bl_idname, link.to_socket.name)
             for link in bound.mesh.data.materials[0].node_tree.links}
    assert {("albedo.png", "Base Color"), ("normal.png", "Color"), ("ShaderNodeNormalMap", "Normal")} <= links
    assert bpy.data.images["normal.png"].colorspace_settings.name == "Non-Color"
