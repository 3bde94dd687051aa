"""The renderer's fused path: the formulas of rasterize.py, interpolate.py, shading.py and
shadow_map.py, computed in fewer and larger passes (`render(..., fused=True)`, the default).

Those modules stay the readable reference (`fused=False`); tests hold the two paths to the
same images and gradients (1e-5) and the same visibility, bit for bit. What changes here is
only how the work is laid out for a CPU:
- gathers read one packed table with flat indices (`index_select`) instead of several
  tensors through multi-dimensional advanced indexing;
- a boolean selection is turned into indices once and reused, not once per tensor;
- the rasteriser enumerates candidate pixels only for faces that have any;
- attributes that share their corner indices are interpolated in one pass;
- the barycentrics, the interpolation, the perturbed normal and the lit colour have
  hand-written backward passes in place of autograd's record of their many small operations;
- the shadow test reads its 3x3 texels in one gather;
- each image is written in one scatter over a copy of what lies behind it;
- the antialiasing finds the silhouette crossings once for all images, and its blend has a
  backward that writes the image's gradient once, instead of a zero image per gather.
The rasteriser does the reference's arithmetic operation for operation, so visibility (which
face wins a pixel, at what depth) is identical; elsewhere sums may round in another order.
"""
from __future__ import annotations

import weakref

import torch
from torch.utils.weak import WeakIdKeyDictionary

from .antialias import EdgeTopology, silhouette_crossings
from .interpolate import Fragments
from .rasterize import _FACE_BITS, NEAR, Rasterization, candidate_test, face_boxes, face_planes, project
from .shading import tangent_weights
from .sparse_operator import SparseOperator, vertex_major
from .vector_ops import cross3, dot3, normalized
from .shadow_map import BIAS, EMPTY_DEPTH, SHARPNESS, filter_taps, light_view


@torch.no_grad()
def rasterize(points, faces, K, height, width, cull_backfaces=True, near=NEAR):
    """rasterize.rasterize, the same result bit for bit."""
    device, dtype = points.device, points.dtype
    batch, num_faces = points.shape[0], faces.shape[0]
    p0, p1, p2, z0, z1, z2, area, x0, y0, box_w, count = face_boxes(points, faces, K, height, width,
                                                                    cull_backfaces, near)
    depth = torch.full((batch * height * width,), float("inf"), dtype=dtype, device=device)
    face_map = torch.full((batch * height * width,), -1, dtype=torch.long, device=device)
    live = torch.nonzero(count).squeeze(1)                            # faces with candidates
    if len(live) == 0:
        return Rasterization(face_map.view(batch, height, width), depth.view(batch, height, width), height, width)
    count = count.index_select(0, live)
    corners = [p.reshape(-1, 2).index_select(0, live) for p in (p0, p1, p2)]
    planes = face_planes(*corners, *(row.reshape(-1).index_select(0, live) for row in (z0, z1, z2, area, x0, y0)))
    hw = height * width
    frame_start = torch.arange(batch, device=device).repeat_interleave(num_faces) * hw
    first_pixel = (frame_start + (y0.reshape(-1) * width + x0.reshape(-1)).long()).index_select(0, live)
    box_width = box_w.reshape(-1).index_select(0, live)
    # one candidate per (live face, pixel in its box)
    owner = torch.repeat_interleave(torch.arange(len(live), device=device), count)
    start = torch.cumsum(count, 0) - count
    offset = torch.arange(len(owner), device=device) - torch.repeat_interleave(start, count)
    # the pixel's row and column in the box, in floating point (whole numbers, exact: a box has
    # far fewer than 2^23 pixels); a CPU divides integers several times slower
    offset, bw = offset.to(dtype), torch.repeat_interleave(box_width, count).to(dtype)
    dy = torch.floor((offset + 0.5) / bw)
    dx = offset - dy * bw
    inside, inverse_depth = candidate_test([plane.index_select(0, owner) for plane in planes], dx, dy)
    inside = torch.nonzero(inside).squeeze(1)                         # one contiguous gather per row above
    cand_depth = 1.0 / inverse_depth.index_select(0, inside)
    inside_owner = owner.index_select(0, inside)
    face_index = live.index_select(0, inside_owner) % num_faces
    pixel = (first_pixel.index_select(0, inside_owner)
             + (dy.index_select(0, inside) * width + dx.index_select(0, inside)).long())
    depth_bits = cand_depth.float().view(torch.int32).long()
    key = (depth_bits << _FACE_BITS) | face_index
    empty = torch.iinfo(torch.long).max
    best = torch.full((batch * height * width,), empty, dtype=torch.long, device=device)
    best.scatter_reduce_(0, pixel, key, reduce="amin")
    hit = torch.nonzero(best != empty).squeeze(1)
    face_map.index_copy_(0, hit, best.index_select(0, hit) & ((1 << _FACE_BITS) - 1))
    is_winner = torch.nonzero(key == best.index_select(0, pixel)).squeeze(1)
    depth.index_copy_(0, pixel.index_select(0, is_winner), cand_depth.index_select(0, is_winner))
    return Rasterization(face_map.view(batch, height, width), depth.view(batch, height, width), height, width)


def fragments(points, faces, K, rast: Rasterization):
    """interpolate.fragments: the corners come from one packed gather of projected vertices."""
    batch, count = points.shape[:2]
    pixel, face = rast.pixel_index()
    hw = rast.height * rast.width
    frame = pixel // hw
    local = pixel % hw
    centre = torch.stack([local % rast.width, local // rast.width], dim=-1).to(points.dtype) + 0.5
    corner = faces.index_select(0, face) + (frame * count).unsqueeze(1)          # (N, 3) into B * V
    # every covered pixel's corners lie beyond the near plane (rasterize culls the rest): the clamp
    # changes no value used, and keeps vertices at the camera from sending back inf * 0
    inverse_z = 1.0 / points[..., 2:3].clamp(min=NEAR)
    vertex_table = torch.cat([project(points, K), inverse_z], dim=-1).reshape(-1, 3)
    corners = vertex_table.index_select(0, corner.reshape(-1)).view(-1, 3, 3)   # x, y, 1/z per corner
    bary = _Barycentrics.apply(corners, centre)
    return Fragments(pixel, frame, face, bary, batch, rast.height, rast.width)


class _Barycentrics(torch.autograd.Function):
    """Perspective-correct barycentrics of pixel centres (N, 2) in triangles given by their
    corners (N, 3, 3): screen x, y and 1/z. The formulas of interpolate.fragments; the
    backward is written out: the screen weights w of a fixed point x = sum_j w_j p_j move with
    a corner p_j as dw / dp_j = -w_j grad_x(w), and grad_x(w) is constant over the triangle."""

    @staticmethod
    def forward(ctx, corners, centre):
        a, b, c = corners[:, 0, :2], corners[:, 1, :2], corners[:, 2, :2]
        area = _cross(b - a, c - a)
        degenerate = area.abs() <= 1e-20
        area = torch.where(degenerate, torch.full_like(area, 1e-20), area)
        w0 = _cross(b - centre, c - centre) / area
        w1 = _cross(c - centre, a - centre) / area
        w2 = 1.0 - w0 - w1
        screen = torch.stack([w0, w1, w2], dim=-1)
        weighted = screen * corners[..., 2]
        total = weighted[:, :1] + weighted[:, 1:2] + weighted[:, 2:3]
        bary = weighted / total
        ctx.save_for_backward(corners, screen, bary, total, area)
        return bary

    @staticmethod
    def backward(ctx, grad):
        corners, screen, bary, total, area = ctx.saved_tensors
        grad_weighted = (grad - dot3(grad, bary)) / total                        # (N, 3)
        grad_inverse_z = grad_weighted * screen
        grad_screen = grad_weighted * corners[..., 2]
        grad_w0 = (grad_screen[:, 0] - grad_screen[:, 2]) / area                  # w2 = 1 - w0 - w1
        grad_w1 = (grad_screen[:, 1] - grad_screen[:, 2]) / area
        # G = sum_i dL/dw_i grad_x(w_i), where area grad_x(w0) = (b - c) turned a quarter, and
        # area grad_x(w1) = (c - a) turned; then dL/dp_j = -w_j G
        x, y = corners[:, :, 0], corners[:, :, 1]
        along_x = grad_w0 * (y[:, 1] - y[:, 2]) + grad_w1 * (y[:, 2] - y[:, 0])
        along_y = grad_w0 * (x[:, 2] - x[:, 1]) + grad_w1 * (x[:, 0] - x[:, 2])
        grad_xy = torch.stack([screen * along_x.unsqueeze(1), screen * along_y.unsqueeze(1)], dim=-1).neg_()
        return torch.cat([grad_xy, grad_inverse_z.unsqueeze(-1)], dim=-1), None


def interpolate(attributes, frags: Fragments, faces):
    """interpolate.interpolate, one flat gather; attributes (B, V, C) per frame or (V, C)."""
    return interpolate_many([attributes], frags, faces)[0]


def interpolate_many(attribute_list, frags: Fragments, faces):
    """Several attributes on the same corners (`faces`) in one pass: a list of (N, C_i).

    Each is (B, V, C_i) per frame or (V, C_i) shared; shared ones are broadcast over the
    frames when any is per frame."""
    per_frame = any(a.dim() == 3 for a in attribute_list)
    corner = faces.index_select(0, frags.face)                                  # (N, 3)
    if per_frame:
        vertices = next(a.shape[1] for a in attribute_list if a.dim() == 3)
        attribute_list = [a if a.dim() == 3 else a.expand(frags.batch, -1, -1) for a in attribute_list]
        corner = corner + (frags.frame * vertices).unsqueeze(1)
    widths = [a.shape[-1] for a in attribute_list]
    table = torch.cat(attribute_list, dim=-1) if len(attribute_list) > 1 else attribute_list[0]
    mixed = _Interpolation.apply(table.reshape(-1, sum(widths)), frags.bary, corner)
    return list(mixed.split(widths, dim=-1))


class _Interpolation(torch.autograd.Function):
    """out[n] = sum_k bary[n, k] * table[corner[n, k]], with a backward that scatters the
    table's gradient in one pass and gathers the corners again rather than keeping them."""

    @staticmethod
    def forward(ctx, table, bary, corner):
        ctx.save_for_backward(table, bary, corner)
        values = table.index_select(0, corner.reshape(-1)).view(-1, 3, table.shape[1])
        # corner by corner: twice as fast on a CPU as a batch of (1, 3) x (3, C) products
        out = values[:, 0] * bary[:, :1]
        out.addcmul_(values[:, 1], bary[:, 1:2])
        return out.addcmul_(values[:, 2], bary[:, 2:3])

    @staticmethod
    def backward(ctx, grad):
        table, bary, corner = ctx.saved_tensors
        grad_table = grad_bary = None
        if ctx.needs_input_grad[0]:
            # one 1-D scatter per channel: twice as fast on a CPU as one scatter of (3N, C) rows
            index = corner.reshape(-1)
            grad_table = torch.stack([table.new_zeros(len(table)).index_add_(0, index, (bary * g[:, None]).reshape(-1))
                                      for g in grad.unbind(1)], dim=1)
        if ctx.needs_input_grad[1]:
            values = table.index_select(0, corner.reshape(-1)).view(-1, 3, table.shape[1])
            grad_bary = torch.bmm(values, grad.unsqueeze(-1)).squeeze(-1)
        return grad_table, grad_bary, None


def perturbed_normal(normal, tangent, handedness, normal_map_value):
    """shading.perturbed_normal with a hand-written backward (its dozen small operations and
    their autograd records were a tenth of a shaded render)."""
    return _PerturbedNormal.apply(normal, tangent, handedness, normal_map_value)


def _unit(vector, eps=1e-12):
    """(rows of (N, 3) made unit length, their lengths (N, 1)); the length component by component
    (dot3), three times as fast as a norm over the last dimension."""
    length = dot3(vector, vector).sqrt().clamp(min=eps)
    return vector / length, length


class _PerturbedNormal(torch.autograd.Function):
    # forward, as shading.perturbed_normal: n = unit(normal); u = tangent - (tangent . n) n;
    # t = unit(u); b = h (n x t); s = m0 t + m1 b + m2 n; out = unit(s). Backward: the chain rule
    # through each step; unit(x)'s Jacobian is (I - y y^T) / |x|.

    @staticmethod
    def forward(ctx, normal, tangent, handedness, value):
        n, normal_length = _unit(normal)
        along = dot3(tangent, n)
        t, tangent_length = _unit(tangent - along * n)
        b = handedness[:, None] * cross3(n, t)
        out, out_length = _unit(value[:, :1] * t + value[:, 1:2] * b + value[:, 2:3] * n)
        ctx.save_for_backward(tangent, handedness, value, n, t, b, out, normal_length, tangent_length,
                              out_length, along)
        return out

    @staticmethod
    def backward(ctx, grad):
        tangent, handedness, value, n, t, b, out, normal_length, tangent_length, out_length, along = ctx.saved_tensors
        grad_s = (grad - out * dot3(out, grad)) / out_length
        grad_value = torch.cat([dot3(grad_s, t), dot3(grad_s, b), dot3(grad_s, n)], dim=-1)
        grad_b = handedness[:, None] * value[:, 1:2] * grad_s
        grad_t = value[:, :1] * grad_s + cross3(grad_b, n)      # a . (n x t) = t . (a x n)
        grad_n = value[:, 2:3] * grad_s + cross3(t, grad_b)     # ... = n . (t x a)
        grad_u = (grad_t - t * dot3(t, grad_t)) / tangent_length
        grad_tangent = grad_u - n * dot3(n, grad_u)
        grad_n = grad_n - along * grad_u - dot3(n, grad_u) * tangent
        grad_normal = (grad_n - n * dot3(n, grad_n)) / normal_length
        return grad_normal, grad_tangent, None, grad_value


def lit_colour(albedo, normal, position, light_position, ambient, visibility=None):
    """shading.lit_colour with a hand-written backward in place of autograd's record of a score
    of small operations on every fragment (a quarter less time for this step, both ways)."""
    ambient = torch.as_tensor(ambient, dtype=albedo.dtype, device=albedo.device)
    return _LitColour.apply(albedo, normal, position, light_position, ambient, visibility)


class _LitColour(torch.autograd.Function):
    # forward: d = light - position; l = d / |d|; c = n . l; lit = max(c, 0) V;
    # f = a + (1 - a) lit; colour = albedo f. Backward: the chain rule through each step, with
    # unit(d)'s Jacobian (I - l l^T) / |d| and max's gradient where c >= 0 (as torch's clamp).

    @staticmethod
    def forward(ctx, albedo, normal, position, light_position, ambient, visibility):
        to_light, length = _unit(light_position - position)
        cosine = dot3(normal, to_light)
        diffuse = cosine.clamp(min=0)
        lit = diffuse if visibility is None else diffuse * visibility
        factor = ambient + (1 - ambient) * lit
        ctx.save_for_backward(albedo, normal, to_light, length, cosine, diffuse, lit, factor, ambient, visibility)
        ctx.shapes = light_position.shape, ambient.shape
        return albedo * factor

    @staticmethod
    def backward(ctx, grad):
        albedo, normal, to_light, length, cosine, diffuse, lit, factor, ambient, visibility = ctx.saved_tensors
        light_shape, ambient_shape = ctx.shapes
        grad_factor = dot3(grad, albedo)
        grad_lit = grad_factor * (1 - ambient)
        grad_visibility = None if visibility is None else grad_lit * diffuse
        grad_cosine = (grad_lit if visibility is None else grad_lit * visibility) * (cosine >= 0).to(grad.dtype)
        grad_to_light = grad_cosine * normal
        grad_offset = (grad_to_light - to_light * dot3(to_light, grad_to_light)) / length
        return (grad * factor, grad_cosine * to_light, -grad_offset, grad_offset.sum_to_size(light_shape),
                (grad_factor * (1 - lit)).sum_to_size(ambient_shape), grad_visibility)


def vertex_normals(points, faces):
    """shading.vertex_normals as sparse products over the frames laid out vertex-major: each
    face's two edges (F, B * 3) from the positions (V, B * 3), and each vertex's sum of its faces'
    normals from the faces' (their backward passes are the transposed products, not scatters)."""
    batch, count = points.shape[:2]
    operators = _mesh_operators(faces, count, points)
    rows = vertex_major(points)
    e1, e2 = (edges(rows).view(-1, batch, 3) for edges in operators.face_edges)
    face_normals = cross3(e1, e2).view(len(faces), -1)
    return normalized(operators.vertex_faces(face_normals).view(count, batch, 3).transpose(0, 1))


def uv_tangents(points, faces, uvs, faces_uv):
    """shading.uv_tangents as one sparse product: with the UVs fixed, each face's tangent is a
    fixed combination of its edges (shading.tangent_weights) and each UV vertex sums its faces',
    so the (U, B * 3) tangents are one (U, V) matrix times the positions laid out vertex-major."""
    batch, count = points.shape[:2]
    tangents_of, handedness = _mesh_operators(faces, count, points).tangents(uvs, faces_uv)
    tangents = tangents_of(vertex_major(points)).view(len(uvs), batch, 3).transpose(0, 1)
    return tangents, handedness


class _MeshOperators:
    """The sparse operators of one triangle mesh's topology (faces (F, 3) over V vertices): each
    face's edges p1 - p0 and p2 - p0, each vertex's sum over its faces, and the tangents' operator
    of a UV layout (built on first use, again when the UVs change)."""

    def __init__(self, faces, count, like):
        rows = torch.arange(len(faces), device=faces.device)
        ones = torch.ones(len(faces), dtype=torch.float64, device=faces.device)
        # a copy: the faces tensor is the cache's weak key, which this must not keep alive
        self.faces, self.count, self.kind = faces.clone(), count, dict(dtype=like.dtype, device=like.device)
        self.face_edges = tuple(SparseOperator(torch.cat([rows, rows]), torch.cat([faces[:, k], faces[:, 0]]),
                                               torch.cat([ones, -ones]), (len(faces), count), **self.kind)
                                for k in (1, 2))
        self.vertex_faces = SparseOperator(faces.t().reshape(-1), rows.repeat(3), ones.repeat(3),
                                           (count, len(faces)), **self.kind)
        self._tangents = None

    def tangents(self, uvs, faces_uv):
        """(SparseOperator (U, V), handedness (F,)): the UV vertices' tangents from the positions."""
        # the UV tensors known by weak references (an id may be taken by a new tensor) and their
        # versions (a change in place makes new UVs)
        cached, versions = self._tangents, (uvs._version, faces_uv._version)
        if cached is None or cached[0]() is not uvs or cached[1]() is not faces_uv or cached[2] != versions:
            faces = self.faces
            t0, t1, t2 = (uvs.index_select(0, faces_uv[:, k]).double() for k in range(3))
            w1, w2, handedness = tangent_weights(t0, t1, t2)
            # each corner of face f adds w1 (p1 - p0) + w2 (p2 - p0) to its UV vertex
            columns = torch.cat([faces[:, 1], faces[:, 2], faces[:, 0]])
            weights = torch.cat([w1, w2, -(w1 + w2)])
            operator = SparseOperator(faces_uv.t().repeat_interleave(3, dim=0).reshape(-1), columns.repeat(3),
                                      weights.repeat(3), (len(uvs), self.count), **self.kind)
            self._tangents = (weakref.ref(uvs), weakref.ref(faces_uv), versions,
                              (operator, handedness.to(self.kind["dtype"])))
        return self._tangents[3]


_OPERATORS = WeakIdKeyDictionary()     # {faces tensor: {(V, dtype, device): _MeshOperators}}


def _mesh_operators(faces, count, like) -> _MeshOperators:
    """The operators of `faces` over `count` vertices in `like`'s dtype and device, made once per
    faces tensor (a fit's meshes keep theirs) and dropped with it."""
    per_faces = _OPERATORS.setdefault(faces, {})
    key = (count, like.dtype, like.device)
    if key not in per_faces:
        per_faces[key] = _MeshOperators(faces, count, like)
    return per_faces[key]


def shadow_visibility(points, faces, surface_points, surface_frags: Fragments, light_position, resolution=256,
                      target=None, radius=None):
    """shadow_map.shadow_visibility on the fused primitives, for the surface points that the
    camera's fragments `surface_frags` interpolate (`surface_points` is not read: the points'
    positions in the light's frame are interpolated from the mesh's rather than transformed
    one by one, the same numbers since the barycentrics sum to 1, for a gather of three
    corners in place of a 3x3 matrix per point); the soft test on the filter's 4 x 4 texels is
    one primitive with its own backward."""
    batch = points.shape[0]
    rotation, eye, K, in_light = light_view(points, light_position, resolution, target, radius)
    rast = rasterize(in_light, faces, K, resolution, resolution)
    frags = fragments(in_light, faces, K, rast)
    # one texel of padding: the test's texels are clamped to it where they fall off the map
    padded = resolution + 2
    depth_map = torch.full((batch, padded, padded), EMPTY_DEPTH, dtype=points.dtype, device=points.device)
    row, column = frags.pixel % (resolution * resolution) // resolution, frags.pixel % resolution
    inner = (frags.frame * padded + row + 1) * padded + column + 1
    depth_map = depth_map.reshape(-1).index_put((inner,), interpolate(in_light[..., 2:], frags, faces)[:, 0])
    receiver = interpolate(in_light, surface_frags, faces)
    first, weights = filter_taps(project(receiver.unsqueeze(0), K)[0])
    with torch.no_grad():
        taps = torch.arange(4, device=points.device)
        columns = (first[:, :1] + taps).clamp(-1, resolution) + 1                  # (N, 4)
        rows = (first[:, 1:] + taps).clamp(-1, resolution) + 1
        texels = ((surface_frags.frame[:, None, None] * padded + rows[:, :, None]) * padded
                  + columns[:, None, :]).reshape(-1, 16)                           # row by row, as the weights
    return _SoftShadowTest.apply(depth_map, texels, weights, receiver[:, 2:3])


class _SoftShadowTest(torch.autograd.Function):
    """V = sum over the texels of weight * sigmoid(SHARPNESS (z_map[texel] - (z - BIAS))), (N, 1),
    from the flat depth map, the texels (N, T), their weights (N, T; no gradient, as
    shadow_map.filter_taps gives them) and the receivers' depths z (N, 1); the sigmoids are kept
    for the backward."""

    @staticmethod
    def forward(ctx, depth_map, texels, weights, depth):
        soft = depth_map.index_select(0, texels.reshape(-1)).view(texels.shape)
        soft.sub_(depth - BIAS).mul_(SHARPNESS).sigmoid_()
        ctx.save_for_backward(texels, weights, soft)
        ctx.texels_in_map = len(depth_map)
        return (soft * weights).sum(1, keepdim=True)

    @staticmethod
    def backward(ctx, grad):
        texels, weights, soft = ctx.saved_tensors
        scaled = weights * soft * (grad * SHARPNESS)
        slope = torch.addcmul(scaled, scaled, soft, value=-1)                    # w s (1 - s) g, (N, T)
        grad_map = slope.new_zeros(ctx.texels_in_map).index_add_(0, texels.reshape(-1), slope.reshape(-1))
        return grad_map, None, None, -slope.sum(1, keepdim=True)


def composite(values, behind, frags: Fragments):
    """Each layer's fragment values (N, C_i) over the image behind it (B, H, W, C_i): a list of
    images, each written in one scatter into its own copy of what lies behind."""
    shape = (frags.batch, frags.height, frags.width)
    return [_Scatter.apply(b.expand(*shape, b.shape[-1]).clone(memory_format=torch.contiguous_format), v, frags.pixel)
            for v, b in zip(values, behind)]


class _Scatter(torch.autograd.Function):
    """image (B, H, W, C) with its pixels `pixel` (N,) set to values (N, C), in place: the image
    is a new copy, and a second would cost as much. The backward gathers the values' gradient;
    autograd's record of an in-place write into a view copied the whole image's gradient twice."""

    @staticmethod
    def forward(ctx, image, values, pixel):
        ctx.mark_dirty(image)
        ctx.save_for_backward(pixel)
        image.view(-1, image.shape[-1]).index_copy_(0, pixel, values)
        return image

    @staticmethod
    def backward(ctx, grad):
        pixel, = ctx.saved_tensors
        flat = grad.reshape(-1, grad.shape[-1])
        grad_image = grad_values = None
        if ctx.needs_input_grad[0]:
            grad_image = flat.index_fill(0, pixel, 0).view_as(grad)
        if ctx.needs_input_grad[1]:
            grad_values = flat.index_select(0, pixel)
        return grad_image, grad_values, None


def antialias(images, points, K, rast: Rasterization, topology: EdgeTopology):
    """antialias.antialias of each image (B, H, W, C_i) of a list: the crossings found once, the
    same blend with a hand-written backward, written into the images themselves (render's
    composite made them, and nothing else reads them)."""
    crossings = silhouette_crossings(points, K, rast, topology)
    if crossings is None:
        return images
    inside, outside, coverage = crossings
    spills_out = coverage > 0.5
    weight = (coverage - 0.5).abs().unsqueeze(1)
    return [_Blend.apply(image, weight, inside, outside, spills_out) for image in images]


class _Blend(torch.autograd.Function):
    """The antialias blend of antialias.antialias, in place: where an edge spills out, the
    outside pixel gains w (in - out); otherwise the inside pixel gains w (out - in), all values
    read first. Backward: the image's gradient passes through, plus +-w g at the two pixels of
    each crossing, in one scatter (autograd's record of the two gathers made a zero image for
    each)."""

    @staticmethod
    def forward(ctx, image, weight, inside, outside, spills_out):
        flat = image.view(-1, image.shape[-1])
        target = torch.where(spills_out, outside, inside)
        source = torch.where(spills_out, inside, outside)
        delta = flat.index_select(0, source) - flat.index_select(0, target)
        ctx.save_for_backward(weight, source, target, delta)
        ctx.mark_dirty(image)
        flat.index_add_(0, target, weight * delta)
        return image

    @staticmethod
    def backward(ctx, grad):
        weight, source, target, delta = ctx.saved_tensors
        flat = grad.reshape(-1, grad.shape[-1])
        grad_target = flat.index_select(0, target)
        grad_image = grad_weight = None
        if ctx.needs_input_grad[0]:
            # out[target] = image[target] + w (image[source] - image[target])
            spread = grad_target * weight
            grad_image = flat.clone().index_add_(0, torch.cat([source, target]), torch.cat([spread, -spread]))
            grad_image = grad_image.view_as(grad)
        if ctx.needs_input_grad[1]:
            grad_weight = (grad_target * delta).sum(-1, keepdim=True)
        return grad_image, grad_weight, None, None, None


def _cross(u, v):
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
