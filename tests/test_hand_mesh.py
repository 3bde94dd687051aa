"""Geometry of the template: a valid closed surface of adult-hand proportions in every shape."""
import numpy as np
import pytest
import torch

from pipeline.formats import hand_model_file as fmt
from pipeline.handmodel import measurements, mesh_checks
from pipeline.handmodel.subdivision import midpoint_parents, subdivide_model_data


def test_closed_oriented_manifold_without_self_intersections(model_data, mode):
    data = model_data[mode]
    for mesh in (data, subdivide_model_data(data)):
        assert mesh_checks.is_closed_oriented_manifold(mesh.faces, mesh.num_vertices)
        assert mesh_checks.signed_volume(mesh.vertices, mesh.faces) > 0  # outward normals
        assert len(mesh_checks.self_intersections(mesh.vertices, mesh.faces)) == 0


def test_self_intersection_check_finds_a_crossing():
    """The checker itself against an analytic case: two triangles piercing each other."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0],
                         [0.2, 0.2, -0.5], [0.3, 0.2, 0.5], [0.2, 0.3, 0.5]], dtype=float)
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    assert len(mesh_checks.self_intersections(vertices, faces)) == 1
    assert len(mesh_checks.self_intersections(vertices + np.r_[[[0, 0, 0]] * 3, [[0, 0, 2]] * 3], faces)) == 0


def test_resolution_is_in_mano_range(model_data, mode):
    assert 500 <= model_data[mode].num_vertices <= 3000


def test_adult_proportions(model_data):
    data = model_data["hand"]
    assert 0.18 <= measurements.hand_length(data) <= 0.19
    assert 0.08 <= measurements.palm_width(data) <= 0.09
    bones = measurements.segment_lengths(data)
    for name in ("index", "middle", "ring", "pinky"):
        first, second, third = bones[name]
        assert 0.5 <= second / first <= 0.75 and 0.45 <= third / first <= 0.65, name
    assert bones["middle"][0] > bones["index"][0] > bones["pinky"][0]
    assert sum(bones["pinky"]) < sum(bones["index"]) < sum(bones["middle"])


def test_thumb_sits_palmar_and_radial(model_data):
    k = list(model_data["hand"].keypoint_names)
    keypoints = model_data["hand"].keypoints
    tip, index_mcp = keypoints[k.index("thumb_tip")], keypoints[k.index("index_mcp")]
    assert tip[0] > index_mcp[0] + 0.02        # off to the radial side
    assert tip[2] > index_mcp[2] + 0.01        # in front of the palm plane
    assert tip[1] > keypoints[k.index("thumb_mcp")][1]


def test_no_face_inverts_for_betas_in_range(model64, mode):
    model = model64[mode]
    generator = torch.Generator().manual_seed(1)
    axes = torch.cat([3 * torch.eye(model.num_betas), -3 * torch.eye(model.num_betas)])
    corners = 3 * (2 * torch.randint(0, 2, (64, model.num_betas), generator=generator) - 1)
    uniform = 6 * torch.rand(128, model.num_betas, generator=generator, dtype=torch.float64) - 3
    betas = torch.cat([axes.double(), corners.double(), uniform])
    rest = model.data.vertices
    with torch.no_grad():
        shaped, _, _ = model.shaped(betas)
    inverted = mesh_checks.inverted_faces(rest, shaped.numpy(), model.data.faces, threshold=0.1)
    assert not inverted.any()


def test_shape_parameters_do_what_they_say(model64):
    model = model64["arm"]
    names = list(model.data.shape_names)
    data = model.data
    k = list(data.keypoint_names)

    def keypoints(name, value):
        betas = torch.zeros(model.num_betas, dtype=torch.float64)
        betas[names.index(name)] = value
        return model.shaped(betas)[2].numpy()

    def length(points):
        return np.linalg.norm(points[k.index("middle_tip")] - points[k.index("wrist")])

    rest = keypoints("scale", 0)
    assert length(keypoints("scale", 1)) == pytest.approx(1.05 * length(rest))
    for finger in ("index", "middle", "ring", "pinky"):
        longer = keypoints(f"{finger}_length", 1)
        before = np.linalg.norm(rest[k.index(f"{finger}_tip")] - rest[k.index(f"{finger}_mcp")])
        after = np.linalg.norm(longer[k.index(f"{finger}_tip")] - longer[k.index(f"{finger}_mcp")])
        assert after == pytest.approx(1.04 * before, rel=1e-6)
    wide = keypoints("palm_width", 1)
    spread = lambda p: p[k.index("index_mcp")][0] - p[k.index("pinky_mcp")][0]
    assert spread(wide) > spread(rest) * 1.02
    elbow = lambda p: np.linalg.norm(p[k.index("elbow")] - p[k.index("wrist")])
    assert elbow(keypoints("forearm_length", 1)) == pytest.approx(1.05 * elbow(rest), rel=0.01)


def test_forearm_parameters_leave_hand_mode_unchanged(model_data):
    names = list(model_data["hand"].shape_names)
    for name in ("forearm_length", "forearm_girth"):
        assert np.abs(model_data["hand"].shapedirs[:, :, names.index(name)]).max() == 0.0


def test_shape_names_are_documented(model_data):
    data = model_data["hand"]
    assert data.num_betas >= 10
    assert all(len(d) > 10 for d in data.shape_descriptions)
    assert len(set(data.shape_names)) == data.num_betas
    assert data.shape_names[0] == "scale"
    assert fmt.PART_NAMES[data.vertex_parts.max()] in fmt.PART_NAMES


def test_midpoint_parents_carry_values_as_the_subdivision_does(model_data, mode):
    """Every subdivided point is the mean of its two parents (a kept vertex: itself twice), for
    positions as for any value carried over (the coarse displacement grid)."""
    data = model_data[mode]
    finer = subdivide_model_data(data)
    parents = midpoint_parents(data)
    assert parents.shape == (finer.num_vertices, 2)
    np.testing.assert_array_equal(0.5 * (data.vertices[parents[:, 0]] + data.vertices[parents[:, 1]]), finer.vertices)
    kept = parents[:, 0] == parents[:, 1]
    assert kept.sum() == data.num_vertices and set(parents[kept, 0]) == set(range(data.num_vertices))
