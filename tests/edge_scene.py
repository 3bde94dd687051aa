"""A straight shadow edge for the light's tests: a receiving square and, nearer the camera, an
occluding square over half of it (tests/test_area_light.py, tests/test_blender_soft_shadows.py)."""
import torch

from pipeline.render.renderer import RenderMesh


def edge_scene(height):
    """(points (1, 8, 3) float64, RenderMesh): a receiving square at z = 0.5 (camera frame,
    x and y from -0.1 to 0.1 m) and an occluding square `height` nearer the camera over x < 0. A
    light from the camera's left casts the occluder's shadow to the right of its edge, where the
    camera sees the receiver."""
    def square(x0, x1, z):
        return [[x0, -0.1, z], [x1, -0.1, z], [x1, 0.1, z], [x0, 0.1, z]]

    points = torch.tensor([square(-0.1, 0.1, 0.5) + square(-0.1, 0.0, 0.5 - height)], dtype=torch.float64)
    faces = torch.tensor([[0, 2, 1], [0, 3, 2], [4, 6, 5], [4, 7, 6]])
    uvs = torch.tensor([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]], dtype=torch.float64)
    return points, RenderMesh(faces, uvs, torch.tensor([[0, 2, 1], [0, 3, 2], [0, 2, 1], [0, 3, 2]]))
