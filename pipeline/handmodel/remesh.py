"""Make a decimated triangle mesh isotropic: split long edges, flip to Delaunay, relax.

Quadric decimation leaves long thin triangles along cylinders such as fingers; skinning needs
edge rings across each joint, so the template is remeshed towards one target edge length.
New vertices are projected onto the implicit surface by the caller's `project` function.
Boundary edges are left alone. Pure Python over a few thousand edges: about a second.
"""
from __future__ import annotations

import numpy as np


class _Mesh:
    """Faces with an undirected-edge -> faces index, for local edits."""

    def __init__(self, vertices, faces):
        self.vertices = [np.asarray(v, dtype=np.float64) for v in vertices]
        self.faces = [list(map(int, f)) for f in faces]
        self.edge_faces = {}
        for index, face in enumerate(self.faces):
            self._register(index, face)

    def _register(self, index, face):
        for k in range(3):
            self.edge_faces.setdefault(_key(face[k], face[(k + 1) % 3]), set()).add(index)

    def _unregister(self, index, face):
        for k in range(3):
            key = _key(face[k], face[(k + 1) % 3])
            self.edge_faces[key].discard(index)
            if not self.edge_faces[key]:
                del self.edge_faces[key]

    def replace(self, index, face):
        self._unregister(index, self.faces[index])
        self.faces[index] = face
        self._register(index, face)

    def add(self, face):
        self.faces.append(face)
        self._register(len(self.faces) - 1, face)

    def interior_edge(self, a, b):
        """(face index with a->b, its third vertex, face with b->a, its third vertex) or None."""
        faces = self.edge_faces.get(_key(a, b), ())
        if len(faces) != 2:
            return None
        first, second = faces
        f1, f2 = self.faces[first], self.faces[second]
        if _rotate_to(f1, a)[1] != b:
            first, second, f1, f2 = second, first, f2, f1
        f1, f2 = _rotate_to(f1, a), _rotate_to(f2, b)
        if f1[1] != b or f2[1] != a:
            return None
        return first, f1[2], second, f2[2]


def _key(a, b):
    return (a, b) if a < b else (b, a)


def _rotate_to(face, vertex):
    k = face.index(vertex)
    return face[k:] + face[:k]


def split_long_edges(vertices, faces, max_length, project, passes=6):
    mesh = _Mesh(vertices, faces)
    original = len(mesh.vertices)
    for _ in range(passes):
        lengths = {key: np.linalg.norm(mesh.vertices[key[0]] - mesh.vertices[key[1]])
                   for key in mesh.edge_faces}
        long_edges = sorted((length, key) for key, length in lengths.items() if length > max_length)
        if not long_edges:
            break
        for _, (a, b) in reversed(long_edges):
            found = mesh.interior_edge(a, b)
            if found is None:
                continue
            first, c, second, d = found
            mesh.vertices.append(0.5 * (mesh.vertices[a] + mesh.vertices[b]))
            m = len(mesh.vertices) - 1
            mesh.replace(first, [a, m, c])
            mesh.add([m, b, c])
            mesh.replace(second, [b, m, d])
            mesh.add([m, a, d])
        # put this pass's midpoints onto the surface before measuring again
        new = np.arange(original, len(mesh.vertices))
        if len(new):
            projected = project(np.array([mesh.vertices[i] for i in new]))
            for i, point in zip(new, projected):
                mesh.vertices[i] = point
            original = len(mesh.vertices)
    return np.array(mesh.vertices), np.array(mesh.faces, dtype=np.int64)


def _angle(at, p, q):
    u, w = p - at, q - at
    cos = np.dot(u, w) / max(np.linalg.norm(u) * np.linalg.norm(w), 1e-30)
    return np.arccos(np.clip(cos, -1.0, 1.0))


def _normal(p, q, r):
    n = np.cross(q - p, r - p)
    return n / max(np.linalg.norm(n), 1e-30)


def flip_to_delaunay(vertices, faces, passes=8, fold_tolerance=0.7):
    """Flip interior edges whose opposite angles sum past pi (unless that would fold)."""
    mesh = _Mesh(vertices, faces)
    v = mesh.vertices
    for _ in range(passes):
        flipped = 0
        for (a, b) in list(mesh.edge_faces):
            found = mesh.interior_edge(a, b)
            if found is None:
                continue
            first, c, second, d = found
            if c == d or _key(c, d) in mesh.edge_faces:
                continue
            if _angle(v[c], v[a], v[b]) + _angle(v[d], v[a], v[b]) <= np.pi + 1e-6:
                continue
            old = _normal(v[a], v[b], v[c]) + _normal(v[b], v[a], v[d])
            old /= max(np.linalg.norm(old), 1e-30)
            n1, n2 = _normal(v[a], v[d], v[c]), _normal(v[d], v[b], v[c])
            if np.dot(n1, old) < fold_tolerance or np.dot(n2, old) < fold_tolerance:
                continue
            mesh.replace(first, [a, d, c])
            mesh.replace(second, [d, b, c])
            flipped += 1
        if flipped == 0:
            break
    return np.array(mesh.vertices), np.array(mesh.faces, dtype=np.int64)
