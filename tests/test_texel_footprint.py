"""The pixel's footprint in the texture (fit/texel_footprint.py) against analytic cases: a square
facing the camera, the same square tilted, and the texture size the rule picks."""
import math

import pytest
import torch

from pipeline.fit.texel_footprint import fitting_texture_size, pixel_shares
from pipeline.render.renderer import RenderMesh

FOCAL, SIZE, HALF = 100.0, 64, 0.1     # pixels, pixels, metres: the square spans 20 x 20 px at 1 m


def square(uv_extent=1.0, tilt_degrees=0.0):
    """(vertices (1, 4, 3) of a 0.2 m square 1 m in front of the camera, turned by `tilt_degrees`
    about the vertical, its RenderMesh with UVs spanning [0, uv_extent]^2, K (1, 3, 3))."""
    corners = torch.tensor([[-HALF, -HALF, 0.0], [HALF, -HALF, 0.0], [HALF, HALF, 0.0], [-HALF, HALF, 0.0]],
                           dtype=torch.float64)
    angle = math.radians(tilt_degrees)
    turn = torch.tensor([[math.cos(angle), 0, math.sin(angle)], [0, 1, 0], [-math.sin(angle), 0, math.cos(angle)]],
                        dtype=torch.float64)
    vertices = (corners @ turn.T + torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))[None]
    faces = torch.tensor([[0, 2, 1], [0, 3, 2]])
    uvs = torch.tensor([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=torch.float64) * uv_extent
    K = torch.tensor([[[FOCAL, 0, SIZE / 2], [0, FOCAL, SIZE / 2], [0, 0, 1]]], dtype=torch.float64)
    return vertices, RenderMesh(faces, uvs, faces), K


def shares_of(vertices, mesh, K):
    share, drawn = pixel_shares(vertices, mesh, K, SIZE, SIZE)
    if not bool(drawn.any()):       # the other winding faces the camera
        mesh = RenderMesh(mesh.faces.flip(1), mesh.uvs, mesh.faces_uv.flip(1))
        share, drawn = pixel_shares(vertices, mesh, K, SIZE, SIZE)
    return share[drawn], int(drawn.sum())


def test_a_square_facing_the_camera_gives_each_pixel_its_share_of_the_uv_square():
    share, drawn = shares_of(*square())
    assert drawn == pytest.approx(400, abs=45)                      # 20 x 20 px, give or take the edges
    assert torch.allclose(share, torch.full_like(share, 1 / 400), rtol=1e-9)
    quarter, _ = shares_of(*square(uv_extent=0.5))                 # a quarter of the UV square: a quarter each
    assert torch.allclose(quarter, torch.full_like(quarter, 1 / 1600), rtol=1e-9)


def test_a_tilted_square_spends_more_texture_on_each_pixel():
    share, _ = shares_of(*square(tilt_degrees=60.0))
    # seen at 60 degrees the square covers about half the pixels (perspective makes it a trapezoid)
    projected = 400 * math.cos(math.radians(60.0))
    assert float(share.mean()) == pytest.approx(1 / projected, rel=0.05)


def test_the_texture_size_has_texels_two_pixels_across_at_the_median_pixel():
    # a texture 40 px across in the frames: texels 2 px across at 16 of them, not 32
    assert fitting_texture_size(1 / 1600, least=1) == 16
    assert fitting_texture_size(1 / 1600, least=1, texel_pixels=1) == 32   # one pixel across: twice as many
    assert fitting_texture_size(1 / 1600) == 64            # never below the least
    assert fitting_texture_size(1 / 2048 ** 2) == 1024     # exactly two pixels across
    assert fitting_texture_size(1 / 2047 ** 2) == 512
    assert fitting_texture_size(1e-12) == 2048             # capped
    assert fitting_texture_size(float("nan")) == 64        # nothing measured: the least
    for footprint in (3e-5, 2e-6, 5e-7):
        size = fitting_texture_size(footprint)
        assert footprint * (2 * size) ** 2 <= 1 < footprint * (4 * size) ** 2
