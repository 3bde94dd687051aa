"""Texels the clip never showed: filled from what it did show, through the surface.

A UV atlas cuts the hand into charts; a texel at a chart's border has its true neighbours in
another chart, far away in the image. So the fill works on a graph over the texels inside the
charts whose edges join (a) texels next to each other in the atlas and (b) border texels of
different charts that lie next to each other on the rest surface (closer than SEAM_REACH texel
widths in 3D). On that graph the unseen texels take the values that vary least (a screened
harmonic fill): trusted texels are kept, every edge pulls its ends together, texels the frames
barely decide are pulled towards their own value as far as they are trusted (fill_unseen), and a
weak pull (SKIN_PRIOR) towards the median seen colour decides regions the graph leaves undetermined.
Outside the charts every texel takes its nearest chart texel's value, so texture filtering at
chart borders picks up skin, not background.

Seam contrast: the mean colour difference across the seam edges (b), the jump a viewer sees
where two charts meet on the hand.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
import scipy.sparse.linalg
from scipy import ndimage
from scipy.spatial import cKDTree

from ..handmodel.uv_raster import interpolate, rasterize_uv

SEAM_REACH = 1.5        # texel widths (in 3D) within which border texels of two charts are joined
SKIN_PRIOR = 1e-3       # weight of the pull towards the median seen colour, against 1 per edge


@dataclasses.dataclass
class TexelGraph:
    """The texels inside the charts of a UV layout at one texture size, and their edges."""

    inside: np.ndarray      # (T, T) bool: texel centres covered by a UV triangle
    index: np.ndarray       # (T, T) int: row of each inside texel in the graph, -1 outside
    edges: np.ndarray       # (E, 2) atlas neighbours and seam neighbours
    seams: np.ndarray       # (S, 2) the seam edges alone
    texel_width: float      # metres on the rest surface between neighbouring texels (median)


def texel_graph(vertices, faces, uvs, faces_uv, size) -> TexelGraph:
    """The graph of the texture of size `size` on the rest surface (vertices (V, 3), faces (F, 3),
    uvs (U, 2), faces_uv (F, 3))."""
    face, bary = rasterize_uv(uvs, faces_uv, size)
    inside = face >= 0
    index = np.full(inside.shape, -1, np.int64)
    index[inside] = np.arange(inside.sum())
    points = interpolate(face, bary, np.asarray(faces), np.asarray(vertices, dtype=np.float64))[inside]
    grid = []
    for axis in (0, 1):
        a = index[:-1, :] if axis == 0 else index[:, :-1]
        b = index[1:, :] if axis == 0 else index[:, 1:]
        both = (a >= 0) & (b >= 0)
        grid.append(np.stack([a[both], b[both]], 1))
    grid = np.concatenate(grid)
    neighbour_length = np.linalg.norm(points[grid[:, 0]] - points[grid[:, 1]], axis=1)
    texel_width = float(np.median(neighbour_length)) if len(grid) else 1.0
    border = inside & ~ndimage.binary_erosion(inside, structure=np.ones((3, 3), bool), border_value=0)
    border_ids = index[border]
    rows, cols = np.nonzero(border)
    tree = cKDTree(points[border_ids])
    pairs = np.array(sorted(tree.query_pairs(SEAM_REACH * texel_width)), dtype=np.int64).reshape(-1, 2)
    far_in_atlas = np.abs(rows[pairs[:, 0]] - rows[pairs[:, 1]]) + np.abs(cols[pairs[:, 0]] - cols[pairs[:, 1]]) > 3
    seams = border_ids[pairs[far_in_atlas]]
    return TexelGraph(inside, index, np.concatenate([grid, seams]), seams, texel_width)


def hops_from_unseen(trust, graph: TexelGraph, limit):
    """(T, T): each inside texel's distance through the graph, in edges, to the nearest texel whose
    trust is 0 (the fill's), counted up to `limit` (farther, and every outside texel: inf)."""
    t = np.asarray(trust, dtype=np.float64)[graph.inside]
    distance = np.full(graph.inside.shape, np.inf)
    unseen = np.nonzero(t <= 0.0)[0]
    if len(unseen):
        count = len(t)
        ones = np.ones(len(graph.edges))
        adjacency = scipy.sparse.coo_matrix((ones, (graph.edges[:, 0], graph.edges[:, 1])), shape=(count, count))
        distance[graph.inside] = scipy.sparse.csgraph.dijkstra(adjacency.tocsr(), directed=False, indices=unseen,
                                                               min_only=True, limit=limit)
    return distance


def trusted_away_from_fill(trust, graph: TexelGraph, reach):
    """The trust (T, T) with its blending kept to the fill's edge: a texel `reach` metres (on the
    rest surface, through the graph) or farther from every texel the fill makes (trust 0) is kept
    as solved (trust 1), one next to the fill keeps its trust, and between, its distrust falls off
    linearly. A side the frames see mostly edge-on then blends into the fill where it ends the seen
    skin (a real clip that never shows the palm: the thumb's side) and stays as solved where the
    frames decide the skin around it. The seen skin's edge is where it turns from the camera, so it is
    seen edge-on nearly everywhere: a clip that shows palm and back loses some of its tone boundary
    there too (docs/real_footage.md)."""
    trust = np.asarray(trust, dtype=np.float64)
    hops = max(reach / graph.texel_width, 1.0)
    distance = hops_from_unseen(trust, graph, limit=hops + 1.0)
    distrust_kept = np.clip((hops + 1.0 - distance) / hops, 0.0, 1.0)     # 1 next to the fill, 0 at the reach
    return 1.0 - (1.0 - trust) * distrust_kept


def seam_contrast(texture, graph: TexelGraph):
    """Mean absolute colour difference (over channels) across the seam edges; texture (T, T, C)."""
    values = np.asarray(texture, dtype=np.float64)[graph.inside]
    if not len(graph.seams):
        return 0.0
    return float(np.abs(values[graph.seams[:, 0]] - values[graph.seams[:, 1]]).mean())


def fill_unseen(texture, trust, graph: TexelGraph):
    """The texture (T, T, C) with every inside texel not fully trusted filled from the others through
    the graph (module docstring), and every outside texel from its nearest inside texel. `trust`
    (T, T), bool or in [0, 1]: 1 keeps a texel's value, 0 fills it as unseen, and between, the texel
    is pulled towards its own value with t / (1 - t) the weight of one edge, so a thinly or only
    edge-on seen texel blends into its neighbours instead of ending the fill in a hard line."""
    texture = np.asarray(texture, dtype=np.float64)
    values = texture[graph.inside].copy()
    t = np.clip(np.asarray(trust, dtype=np.float64)[graph.inside], 0.0, 1.0)
    kept, seen = t >= 1.0, t > 0.0
    if seen.any() and not kept.all():
        count = len(values)
        weights = np.ones(len(graph.edges))
        adjacency = scipy.sparse.coo_matrix((np.concatenate([weights, weights]),
                                             (np.concatenate([graph.edges[:, 0], graph.edges[:, 1]]),
                                              np.concatenate([graph.edges[:, 1], graph.edges[:, 0]]))),
                                            shape=(count, count)).tocsr()
        laplacian = scipy.sparse.diags(np.asarray(adjacency.sum(1)).ravel()) - adjacency
        free = np.nonzero(~kept)[0]
        own = t[free] / (1.0 - t[free])    # each free texel's pull to its own value (0 where unseen)
        system = laplacian[free][:, free] + scipy.sparse.diags(own + SKIN_PRIOR)
        prior = np.median(values[seen], axis=0)
        right = (-laplacian[free][:, np.nonzero(kept)[0]] @ values[kept] + own[:, None] * values[free]
                 + SKIN_PRIOR * prior)
        values[free] = scipy.sparse.linalg.splu(system.tocsc()).solve(right)
    filled = texture.copy()
    filled[graph.inside] = values
    return extend_outside(filled, graph.inside)


def extend_outside(texture, inside):
    """The texture (T, T, C) with every texel outside the charts (`inside` (T, T) False) taking
    its nearest chart texel's value: filtering at a chart's border then mixes in only the hand's."""
    texture = np.array(texture, copy=True)
    _, nearest = ndimage.distance_transform_edt(~inside, return_indices=True)
    outside = ~inside
    texture[outside] = texture[nearest[0][outside], nearest[1][outside]]
    return texture


def fill_avatar_albedo(avatar, trust, blend_reach=None) -> dict:
    """Fill the texels of the avatar's albedo that its frames do not decide and blend those they
    barely decide into the fill (`trust` (T, T): albedo_solve.texel_trust, or decided_texels' bool;
    with `blend_reach`, metres, only within that reach of the fill: trusted_away_from_fill), and
    the normal map's outside the charts (in place, under no_grad); returns the shares filled
    (trust 0) and blended (between 0 and 1), and the seam contrast before and after.

    Undecided is more than unseen: a texel the frames show only at the silhouette, outside the
    pixels the fit compares (a finger's side seen edge-on), was never fitted and still holds the
    albedo's starting colour. Kept as seen, those were pale streaks along the fingers' sides in
    new poses (docs/fidelity.md)."""
    import torch

    size = avatar.albedo.shape[-1]
    data = avatar.model.data
    with torch.no_grad():
        trust = np.asarray(trust.cpu().numpy(), dtype=np.float64)
        graph = texel_graph(avatar.rest_mesh().cpu().numpy(), data.faces, data.uvs, data.faces_uv, size)
        if blend_reach is not None:
            trust = trusted_away_from_fill(trust, graph, blend_reach)
        albedo = avatar.albedo.clamp(0, 1).permute(1, 2, 0).cpu().double().numpy()
        filled = fill_unseen(albedo, trust, graph)
        avatar.albedo.copy_(torch.as_tensor(filled, dtype=avatar.albedo.dtype).permute(2, 0, 1))
        # the normal map's texels outside the charts get gradients through filtering but no
        # regulariser: left as fitted, they tilt up to 40 degrees (a real clip) along the seams
        normals = avatar.normal_map.permute(1, 2, 0).cpu().double().numpy()
        avatar.normal_map.copy_(torch.as_tensor(extend_outside(normals, graph.inside),
                                                dtype=avatar.normal_map.dtype).permute(2, 0, 1))
    inside = max(graph.inside.sum(), 1)
    return {"unseen_fraction": float((graph.inside & (trust <= 0)).sum() / inside),
            "blended_fraction": float((graph.inside & (trust > 0) & (trust < 1)).sum() / inside),
            "seam_contrast_before": seam_contrast(albedo, graph), "seam_contrast_after": seam_contrast(filled, graph)}
