"""UV atlas of the template (xatlas) and the mask of the used UV area.

UVs follow the OpenGL/Blender convention (v up); in an image of the atlas row 0 is v = 1.
"""
from __future__ import annotations

import cv2
import numpy as np

ATLAS_RESOLUTION = 1024
ATLAS_PADDING = 6


def make_atlas(vertices, faces, chart_costs=(2.0, 4.0, 8.0, 16.0)):
    """The atlas with the fewest charts over a few chart-growing costs (ties: the most even
    texel density): (uvs (U, 2) float64, faces_uv (F, 3) int32, number of charts)."""
    best = None
    for cost in chart_costs:
        uvs, faces_uv, charts = atlas_for_cost(vertices, faces, cost)
        score = (charts, texel_density_spread(vertices, faces, uvs, faces_uv))
        if best is None or score < best[0]:
            best = (score, uvs, faces_uv, charts)
    return best[1:]


def atlas_for_cost(vertices, faces, max_cost):
    """xatlas charts and packing: a higher cost grows fewer, larger charts; all charts are
    packed at one texel density."""
    import xatlas

    atlas = xatlas.Atlas()
    atlas.add_mesh(np.ascontiguousarray(vertices, dtype=np.float32),
                   np.ascontiguousarray(faces, dtype=np.uint32))
    chart_options = xatlas.ChartOptions()
    chart_options.max_cost = max_cost
    chart_options.max_iterations = 4
    chart_options.normal_seam_weight = 1.0
    chart_options.roundness_weight = 0.05
    chart_options.straightness_weight = 3.0
    pack_options = xatlas.PackOptions()
    pack_options.resolution = ATLAS_RESOLUTION
    pack_options.padding = ATLAS_PADDING
    pack_options.bilinear = True
    pack_options.rotate_charts = True
    atlas.generate(chart_options, pack_options)
    vmapping, indices, uvs = atlas[0]
    if not (vmapping[indices] == faces).all():
        raise RuntimeError("xatlas reordered the faces")
    return np.asarray(uvs, dtype=np.float64), np.asarray(indices, dtype=np.int32), atlas.chart_count


def uv_mask(uvs, faces_uv, resolution=512, dilation_px=1):
    """(resolution, resolution) bool image of the UV area covered by faces (row 0 = v 1)."""
    mask = np.zeros((resolution, resolution), np.uint8)
    pixels = np.stack([uvs[:, 0] * resolution, (1.0 - uvs[:, 1]) * resolution], axis=1) - 0.5
    polygons = np.round(pixels[faces_uv] * 16).astype(np.int32)
    for polygon in polygons:
        cv2.fillConvexPoly(mask, polygon, 1, lineType=cv2.LINE_8, shift=4)
    if dilation_px > 0:
        kernel = np.ones((2 * dilation_px + 1,) * 2, np.uint8)
        mask = cv2.dilate(mask, kernel)
    return mask.astype(bool)


def texel_density_spread(vertices, faces, uvs, faces_uv):
    """Relative spread (std / mean, area-weighted) of UV area per surface area over faces."""
    tri = vertices[faces]
    area3d = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    t = uvs[faces_uv]
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    area_uv = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    ratio = np.sqrt(area_uv / np.maximum(area3d, 1e-30))
    mean = np.average(ratio, weights=area3d)
    return float(np.sqrt(np.average((ratio - mean) ** 2, weights=area3d)) / mean)
