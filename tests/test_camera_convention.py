"""Our OpenCV camera and Blender's camera agree: Blender's own projection of points equals ours."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pipeline.formats import camera

bpy = pytest.importorskip("bpy")
from bpy_extras.object_utils import world_to_camera_view  # noqa: E402
from mathutils import Matrix, Vector  # noqa: E402


@pytest.mark.parametrize("width, height, K", [
    (448, 448, [[2000, 0, 224], [0, 2000, 224], [0, 0, 1]]),
    (640, 360, [[500, 0, 300], [0, 500, 200], [0, 0, 1]]),      # off-centre principal point
    (300, 500, [[420, 0, 160], [0, 420, 240], [0, 0, 1]]),      # portrait
])
def test_blender_projects_like_opencv(width, height, K):
    K = np.array(K, dtype=float)
    rng = np.random.default_rng(0)
    R = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    t = np.array([0.02, -0.01, 0.6])
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    settings = camera.blender_camera_settings(K, width, height)
    data = bpy.data.cameras.new("test_camera")
    for key in ("lens", "sensor_width", "sensor_fit", "shift_x", "shift_y"):
        setattr(data, key, settings[key])
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
    obj = bpy.data.objects.new("test_camera", data)
    scene.collection.objects.link(obj)
    obj.matrix_world = Matrix(camera.blender_camera_matrix_world(R, t).tolist())
    bpy.context.view_layer.update()
    points = rng.normal(scale=0.05, size=(20, 3))
    ours, depth = camera.project(points, K, R, t)
    for point, pixel, z in zip(points, ours, depth):
        ndc = world_to_camera_view(scene, obj, Vector(point.tolist()))
        blender_pixel = np.array([ndc.x * width, (1 - ndc.y) * height])
        np.testing.assert_allclose(blender_pixel, pixel, atol=1e-3)
        assert ndc.z == pytest.approx(z, abs=1e-6)
    R_back, t_back = camera.opencv_extrinsics_from_blender(np.array(obj.matrix_world))
    np.testing.assert_allclose(R_back, R, atol=1e-6)
    np.testing.assert_allclose(t_back, t, atol=1e-6)
    bpy.data.objects.remove(obj)
    bpy.data.cameras.remove(data)


def test_non_square_pixels_are_refused():
    with pytest.raises(ValueError, match="non-square"):
        camera.blender_camera_settings([[500, 0, 100], [0, 510, 100], [0, 0, 1]], 200, 200)


def test_fov_intrinsics():
    K = camera.intrinsics_from_fov(448, 448, 2 * np.degrees(np.arctan(224 / 2000)))
    np.testing.assert_allclose(K, [[2000, 0, 224], [0, 2000, 224], [0, 0, 1]])
