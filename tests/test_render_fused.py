"""The fused render path against the reference primitives: the same visibility bit for bit, the
same images and gradients to 1e-5 (float64), and the hand-written backward passes against
finite differences."""
import numpy as np
import pytest
import torch

from pipeline.handmodel.lbs import HandModel
from pipeline.handmodel.poses import NAMED_POSES
from pipeline.render import fused, rasterize, shading
from pipeline.render.occlusion import lost_light
from pipeline.render.renderer import OUTPUTS, Appearance, Light, RenderMesh, falloff_reach, lobe_colour, render
from render_meshes import intrinsics

SIZE = 96


@pytest.fixture(scope="module")
def hand_scene():
    """Two frames of the subdivided hand in different poses, float64, with textures and a light."""
    model = HandModel.load("hand", subdivided=True)
    names = ["spread", "fist"]
    pose = torch.as_tensor(np.stack([NAMED_POSES[name] for name in names]), dtype=torch.float32)
    orient = torch.tensor([[np.pi, 0.0, 0.0], [np.pi - 0.5, 0.4, 0.2]])
    transl = torch.tensor([[0.0, 0.09, 0.45], [0.01, 0.08, 0.5]])
    with torch.no_grad():
        points = model(pose=pose, global_orient=orient, transl=transl).vertices.double()
    mesh = RenderMesh.from_model_data(model.data, dtype=torch.float64)
    generator = torch.Generator().manual_seed(3)
    albedo = 0.4 + 0.4 * torch.rand(3, 64, 64, generator=generator, dtype=torch.float64)
    up = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)[:, None, None]
    normal_map = torch.nn.functional.normalize(
        torch.randn(3, 64, 64, generator=generator, dtype=torch.float64) * 0.2 + up, dim=0)
    K = torch.stack([intrinsics(220.0, SIZE, SIZE), intrinsics(200.0, SIZE, SIZE)]).double()
    return points, mesh, albedo, normal_map, K


def _render_with_gradients(scene, fused_path, light_per_frame=False, falloff=False):
    points, mesh, albedo, normal_map, K = scene
    leaves = {"points": points.clone().requires_grad_(True), "albedo": albedo.clone().requires_grad_(True),
              "normal_map": normal_map.clone().requires_grad_(True),
              "light": (torch.tensor([[0.25, -0.3, 0.1], [0.1, -0.2, 0.2]]) if light_per_frame
                        else torch.tensor([0.25, -0.3, 0.1])).double().requires_grad_(True),
              "ambient": torch.tensor(0.4, dtype=torch.float64, requires_grad=True)}
    background = torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)
    images = render(leaves["points"], mesh, K, SIZE, SIZE, outputs=OUTPUTS,
                    appearance=Appearance(leaves["albedo"], leaves["normal_map"]),
                    light=Light(leaves["light"], leaves["ambient"], shadows=True, shadow_resolution=64,
                                occlusion=lost_light(points, mesh.faces), falloff=0.45 if falloff else 0.0),
                    background=background, fused=fused_path, vertex_values=leaves["points"])
    generator = torch.Generator().manual_seed(5)
    loss = sum((torch.nan_to_num(image, posinf=0.0) * torch.rand(image.shape, generator=generator,
                                                                  dtype=image.dtype)).sum()
               for name, image in images.items() if name != "depth")
    loss.backward()
    return {name: image.detach() for name, image in images.items()}, {name: leaf.grad for name, leaf in leaves.items()}


@pytest.mark.parametrize("light_per_frame,falloff", [(False, False), (True, False), (True, True)])
def test_fused_and_reference_paths_agree(hand_scene, light_per_frame, falloff):
    reference_images, reference_grads = _render_with_gradients(hand_scene, False, light_per_frame, falloff)
    fused_images, fused_grads = _render_with_gradients(hand_scene, True, light_per_frame, falloff)
    assert reference_images["alpha"].sum() > 1000            # the hand is in view
    for name, image in reference_images.items():
        assert torch.equal(torch.isinf(image), torch.isinf(fused_images[name])), name
        finite = torch.isfinite(image)
        assert torch.allclose(fused_images[name][finite], image[finite], atol=1e-5, rtol=0), name
    for name, grad in reference_grads.items():
        assert grad.abs().max() > 0, name
        assert torch.allclose(fused_grads[name], grad, atol=1e-5 * grad.abs().max(), rtol=0), name
    # a per-vertex value interpolated over the faces as the surface is: the vertices give back the surface point
    inside = reference_images["alpha"][..., 0] > 0
    for images in (reference_images, fused_images):
        assert torch.allclose(images["vertex_values"][inside], images["position"][inside], atol=1e-9, rtol=0)

@pytest.mark.parametrize("light_per_frame,falloff", [(False, False), (True, False), (False, True)])
def test_the_lobes_share_from_one_renders_outputs(hand_scene, light_per_frame, falloff):
    """lobe_colour on a render's shading_normal, position, light_visibility and lost_light is the
    lobe's share of rgb: what the same light gives an albedo of 0 (shadows, the room light's
    occlusion, an environment light and a light per frame all on)."""
    points, mesh, albedo, normal_map, K = hand_scene
    generator = torch.Generator().manual_seed(11)
    position = (torch.tensor([[0.25, -0.3, 0.1], [0.1, -0.2, 0.2]]) if light_per_frame
                else torch.tensor([0.25, -0.3, 0.1])).double()
    light = Light(position, torch.tensor(0.4, dtype=torch.float64), shadows=True, shadow_resolution=64,
                  environment=0.1 * torch.randn(8, 3, generator=generator, dtype=torch.float64),
                  specular=(torch.tensor(0.45, dtype=torch.float64), torch.tensor(0.5, dtype=torch.float64)),
                  occlusion=lost_light(points, mesh.faces), falloff=0.45 if falloff else 0.0)
    images = render(points, mesh, K, SIZE, SIZE, outputs=("rgb", "alpha", "shading_normal", "position",
                                                          "light_visibility", "lost_light"),
                    appearance=Appearance(albedo, normal_map), light=light, antialiased=False)
    lobe_only = render(points, mesh, K, SIZE, SIZE, outputs=("rgb",), light=light, antialiased=False,
                       appearance=Appearance(torch.zeros_like(albedo), normal_map))["rgb"]
    covered = images["alpha"][..., 0] > 0.5
    visibility = images["light_visibility"][covered]
    assert covered.sum() > 1000 and visibility.min() < 0.5 and visibility.max() > 0.99    # some of it in shadow
    reach = falloff_reach(light, points)
    frame = covered.nonzero()[:, 0]
    lobe = lobe_colour(images["shading_normal"][covered], images["position"][covered], light, frame, visibility,
                       images["lost_light"][covered], None if reach is None else reach[frame])
    assert lobe.shape == (int(covered.sum()), 3) and lobe.max() > 0.02
    assert torch.allclose(lobe, lobe_only[covered], atol=1e-12, rtol=0)
    # the position is the surface's: it projects to its pixel's centre
    pixels = covered.nonzero()
    projected = torch.einsum("nij,nj->ni", K[pixels[:, 0]], images["position"][covered])
    centres = torch.stack([pixels[:, 2], pixels[:, 1]], -1).double() + 0.5
    assert torch.allclose(projected[:, :2] / projected[:, 2:], centres, atol=1e-6)
    unshadowed = render(points, mesh, K, SIZE, SIZE, outputs=("rgb", "light_visibility"), light=Light(
        position, torch.tensor(0.4, dtype=torch.float64)), appearance=Appearance(albedo))["light_visibility"]
    assert torch.equal(unshadowed[covered], torch.ones_like(unshadowed[covered]))


def test_fused_normals_and_tangents_are_the_references_at_every_vertex(hand_scene):
    """The sparse products give every vertex's normal, every UV vertex's tangent and every face's
    handedness as shading.py's gathers and scatters do, with the same gradients; UVs changed in
    place make new tangents (the cached matrix is rebuilt)."""
    points, mesh, *_ = hand_scene
    generator = torch.Generator().manual_seed(7)
    weights = torch.rand(2, len(points[0]), 3, generator=generator, dtype=torch.float64), \
        torch.rand(2, len(mesh.uvs), 3, generator=generator, dtype=torch.float64)
    results = []
    for ops in (shading, fused):
        leaf = points.clone().requires_grad_(True)
        normals = ops.vertex_normals(leaf, mesh.faces)
        tangents, handedness = ops.uv_tangents(leaf, mesh.faces, mesh.uvs, mesh.faces_uv)
        ((normals * weights[0]).sum() + (tangents * weights[1]).sum()).backward()
        results.append((normals.detach(), tangents.detach(), handedness, leaf.grad))
    (normals, tangents, handedness, grad), (fused_normals, fused_tangents, fused_handedness, fused_grad) = results
    assert (handedness < 0).any() and (handedness > 0).any()         # the atlas has mirrored charts
    assert torch.equal(fused_handedness, handedness)
    assert torch.allclose(fused_normals, normals, atol=1e-12, rtol=0)
    assert torch.allclose(fused_tangents, tangents, atol=1e-12 * tangents.abs().max(), rtol=0)
    assert torch.allclose(fused_grad, grad, atol=1e-10 * grad.abs().max(), rtol=0)
    uvs = mesh.uvs.clone()
    expected = shading.uv_tangents(points, mesh.faces, uvs * torch.tensor([2.0, 1.0], dtype=uvs.dtype), mesh.faces_uv)[0]
    fused.uv_tangents(points, mesh.faces, uvs, mesh.faces_uv)
    uvs[:, 0] *= 2.0                                                   # u stretched: tangents halve
    assert torch.allclose(fused.uv_tangents(points, mesh.faces, uvs, mesh.faces_uv)[0], expected,
                          atol=1e-12 * expected.abs().max(), rtol=0)



@pytest.mark.parametrize("size", [SIZE, 131])
def test_fused_rasteriser_is_the_reference_bit_for_bit(hand_scene, size):
    points, mesh, _, _, K = hand_scene
    for dtype in (torch.float64, torch.float32):
        moved = points.to(dtype) + torch.tensor([0.003, -0.002, 0.0], dtype=dtype)
        camera = intrinsics(2.2 * size, size, size).to(dtype)
        expected = rasterize.rasterize(moved, mesh.faces, camera, size, size)
        got = fused.rasterize(moved, mesh.faces, camera, size, size)
        assert torch.equal(got.face, expected.face)
        assert torch.equal(got.depth, expected.depth)
        assert (got.face >= 0).sum() > 100


def test_fused_rasteriser_with_nothing_in_view(hand_scene):
    points, mesh, _, _, K = hand_scene
    behind = points * torch.tensor([1.0, 1.0, -1.0], dtype=points.dtype)
    got = fused.rasterize(behind, mesh.faces, K, SIZE, SIZE)
    assert (got.face == -1).all() and torch.isinf(got.depth).all()


def test_barycentrics_backward_matches_finite_differences():
    generator = torch.Generator().manual_seed(0)
    count = 30
    corners = torch.rand(count, 3, 3, generator=generator, dtype=torch.float64)
    corners = corners * torch.tensor([12.0, 12.0, 1.0]).double() + torch.tensor([0.0, 0.0, 1.0]).double()
    centre = torch.rand(count, 2, generator=generator, dtype=torch.float64) * 12
    corners.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda c: fused._Barycentrics.apply(c, centre), (corners,))


def test_perturbed_normal_backward_matches_finite_differences():
    generator = torch.Generator().manual_seed(1)
    count = 30
    normal, tangent, value = (torch.randn(count, 3, generator=generator, dtype=torch.float64).requires_grad_(True)
                              for _ in range(3))
    handedness = torch.where(torch.rand(count, generator=generator) < 0.5, -1.0, 1.0).double()
    assert torch.autograd.gradcheck(lambda n, t, m: fused.perturbed_normal(n, t, handedness, m),
                                    (normal, tangent, value))


def test_interpolation_backward_matches_finite_differences():
    generator = torch.Generator().manual_seed(2)
    table = torch.randn(10, 4, generator=generator, dtype=torch.float64).requires_grad_(True)
    bary = torch.rand(25, 3, generator=generator, dtype=torch.float64).requires_grad_(True)
    corner = torch.randint(0, 10, (25, 3), generator=generator)
    assert torch.autograd.gradcheck(lambda t, b: fused._Interpolation.apply(t, b, corner), (table, bary))


@pytest.mark.parametrize("per_fragment", [False, True])
def test_lit_colour_backward_matches_finite_differences(per_fragment):
    """The light (one, or one per fragment's frame), the ambient (one, or per fragment) and the
    shadow visibility; cosines kept away from 0, where max(c, 0) has a kink."""
    generator = torch.Generator().manual_seed(4)
    count = 30
    albedo = torch.rand(count, 3, generator=generator, dtype=torch.float64)
    normal = torch.nn.functional.normalize(torch.randn(count, 3, generator=generator, dtype=torch.float64), dim=-1)
    position = torch.randn(count, 3, generator=generator, dtype=torch.float64) * 0.05
    light = torch.tensor([0.3, -0.4, 0.2], dtype=torch.float64)
    if per_fragment:
        light = light + 0.05 * torch.randn(count, 3, generator=generator, dtype=torch.float64)
    to_light = torch.nn.functional.normalize(light - position, dim=-1)
    near_kink = (normal * to_light).sum(-1, keepdim=True).abs() < 0.05
    normal = torch.where(near_kink, to_light, normal)
    ambient = (torch.rand(count, 1, generator=generator, dtype=torch.float64) if per_fragment
               else torch.tensor(0.4, dtype=torch.float64))
    visibility = torch.rand(count, 1, generator=generator, dtype=torch.float64)
    inputs = [t.clone().requires_grad_(True) for t in (albedo, normal, position, light, ambient, visibility)]
    assert torch.autograd.gradcheck(fused.lit_colour, inputs)
    reference = shading.lit_colour(*inputs)
    assert torch.allclose(fused.lit_colour(*inputs), reference, atol=1e-12)
    assert torch.autograd.gradcheck(lambda *a: fused.lit_colour(*a[:5]), inputs[:5])   # no shadows


def test_antialias_blend_backward_matches_finite_differences():
    """Crossings that share pixels (a pixel both blended into and read from, twice), both ways."""
    generator = torch.Generator().manual_seed(5)
    flat = torch.rand(12, 4, generator=generator, dtype=torch.float64).requires_grad_(True)
    weight = torch.rand(20, 1, generator=generator, dtype=torch.float64).requires_grad_(True)
    inside = torch.randint(0, 12, (20,), generator=generator)
    outside = torch.randint(0, 12, (20,), generator=generator)
    spills_out = torch.rand(20, generator=generator) < 0.5
    # the blend writes into its image: give it a copy each time
    assert torch.autograd.gradcheck(lambda f, w: fused._Blend.apply(f.clone(), w, inside, outside, spills_out),
                                    (flat, weight))


def test_soft_shadow_test_backward_matches_finite_differences():
    """Receivers near the occluders' depths (where the sigmoid has a slope), texels repeated."""
    generator = torch.Generator().manual_seed(6)
    depth_map = (0.5 + 0.01 * torch.rand(16, generator=generator, dtype=torch.float64)).requires_grad_(True)
    texels = torch.randint(0, 16, (10, 16), generator=generator)
    weights = torch.rand(10, 16, generator=generator, dtype=torch.float64)
    weights = weights / weights.sum(1, keepdim=True)
    depth = (0.505 + 0.01 * torch.rand(10, 1, generator=generator, dtype=torch.float64)).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda m, z: fused._SoftShadowTest.apply(m, texels, weights, z), (depth_map, depth))


def test_shadow_visibility_agrees_where_points_fall_off_the_map(hand_scene):
    """A shadow camera framing only part of the hand: surface points project onto the map's
    border texels and beyond it, where the reference clamps into its padding and the fused
    path reads a wider padding. Values and gradients agree."""
    from pipeline.render import interpolate, shadow_map

    points, mesh, _, _, K = hand_scene
    light = torch.tensor([0.25, -0.3, 0.1], dtype=torch.float64)
    target = points[0].mean(0) + torch.tensor([0.02, 0.0, 0.0], dtype=torch.float64)
    results = []
    for path in ("reference", "fused"):
        leaf = points.clone().requires_grad_(True)
        rast = rasterize.rasterize(leaf.detach(), mesh.faces, K, SIZE, SIZE)
        frags = interpolate.fragments(leaf, mesh.faces, K, rast)
        position = interpolate.interpolate(leaf, frags, mesh.faces)
        if path == "reference":
            visibility = shadow_map.shadow_visibility(leaf, mesh.faces, position, frags.frame, light, 32, target, 0.03)
        else:
            visibility = fused.shadow_visibility(leaf, mesh.faces, position, frags, light, 32, target, 0.03)
        visibility.sum().backward()
        results.append((visibility.detach(), leaf.grad))
        if path == "reference":   # some points beyond the map's edge see its empty padding
            rotation, eye, light_K, _ = shadow_map.light_view(leaf.detach(), light, 32, target, 0.03)
            receiver = torch.einsum("nij,nj->ni", rotation[frags.frame], position.detach() - eye[frags.frame])
            texel = rasterize.project(receiver.unsqueeze(0), light_K)[0]
            assert ((texel < 0) | (texel >= 32)).any(1).float().mean() > 0.05
    (reference, reference_grad), (fused_values, fused_grad) = results
    assert reference.min() < 0.5 < reference.max() and reference_grad.abs().max() > 0
    assert torch.allclose(fused_values, reference, atol=1e-9, rtol=0)
    assert torch.allclose(fused_grad, reference_grad, atol=1e-9 * reference_grad.abs().max(), rtol=0)


@pytest.mark.parametrize("path", [rasterize.rasterize, fused.rasterize])
def test_rasteriser_depth_is_the_planes_along_each_pixel_ray(path):
    """Two large tilted triangles (boxes of hundreds of pixels, where the inverse depth is stepped
    furthest from each box's first pixel) in float32: every covered pixel's depth is the exact
    ray-plane intersection, and the coverage is the triangles' analytic inside test."""
    size = 256
    K = intrinsics(300.0, size, size).float()
    quad = torch.tensor([[-0.2, -0.2, 0.6], [0.2, -0.2, 0.9], [0.2, 0.2, 1.0], [-0.2, 0.2, 0.7]])
    faces = torch.tensor([[0, 2, 1], [0, 3, 2]])      # front-facing: negative signed area with y down
    rast = path(quad.unsqueeze(0), faces, K, size, size)
    normal = torch.cross(quad[1] - quad[0], quad[2] - quad[0], dim=0).double()
    v, u = torch.meshgrid(torch.arange(size) + 0.5, torch.arange(size) + 0.5, indexing="ij")
    rays = torch.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], torch.ones_like(u)], dim=-1).double()
    exact = (normal @ quad[0].double()) / (rays @ normal)          # z along each ray (its z is 1)
    covered = rast.face[0] >= 0
    assert covered.sum() > 10000
    assert torch.allclose(rast.depth[0][covered].double(), exact[covered], rtol=2e-6, atol=0)
    projected = rasterize.project(quad.unsqueeze(0), K)[0].double()
    pixel = torch.stack([u, v], dim=-1).double()
    strictly_inside = _strictly_inside(pixel, *projected[[0, 2, 1]]) | _strictly_inside(pixel, *projected[[0, 3, 2]])
    assert covered[strictly_inside].all()


def _strictly_inside(pixel, a, b, c):
    """(H, W) bool: pixel centres inside triangle a, b, c by a margin that rounding cannot cross."""
    values = torch.stack([(q[0] - p[0]) * (pixel[..., 1] - p[1]) - (q[1] - p[1]) * (pixel[..., 0] - p[0])
                          for p, q in [(b, c), (c, a), (a, b)]])
    return values.le(-1e-3).all(0) | values.ge(1e-3).all(0)
