"""Blocks of tetrahedral elements (seed 003, Fig. 1a): cubes split into 6 tetrahedra.

Each cube of edge h is split along its main diagonal (0,0,0)-(1,1,1) into the six
tetrahedra 0, e_a, e_a + e_b, (1,1,1) for the six orders (a, b, c) of the axes (Freudenthal's
split); every cube is split the same way, so neighbouring cubes share their face diagonals
and the mesh is conforming.  4 x 4 x 4 cubes give the paper's 384 elements, 8 x 8 x 8 its 3072,
4 x 4 x 40 its 3840.

A periodic axis has no vertices on its upper face: a cube at the end uses the vertices at 0
with an image shift of one box length (``shift``, per element vertex), so an element's
vertex positions are ``x[tets] + shift * box`` and the box can be stretched.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

AXES = "xyz"


@dataclass
class Mesh:
    """Vertices (V, 3) and tetrahedra (E, 4) of a block; lengths in nm."""

    vertices: np.ndarray
    tets: np.ndarray
    shift: np.ndarray            # (E, 4, 3) image shifts of each element vertex, in box lengths
    box: np.ndarray              # (3,) box lengths (nm); meaningful along the periodic axes
    periodic: tuple[bool, bool, bool]
    cubes: tuple[int, int, int]
    cube_nm: float

    @property
    def elements(self) -> int:
        return len(self.tets)

    def element_vertices(self, x: np.ndarray, box: np.ndarray | None = None) -> np.ndarray:
        """Positions (E, 4, 3) of each element's vertices, periodic images applied."""
        return x[self.tets] + self.shift * (self.box if box is None else box)

    def shape_matrices(self, x: np.ndarray, box: np.ndarray | None = None) -> np.ndarray:
        """(r1 - r0 | r2 - r0 | r3 - r0) of every element, (E, 3, 3) (eq. 5)."""
        p = self.element_vertices(x, box)
        return np.transpose(p[:, 1:] - p[:, :1], (0, 2, 1))

    def volumes(self, x: np.ndarray | None = None, box: np.ndarray | None = None) -> np.ndarray:
        """Element volumes (nm^3) at positions x (the reference by default)."""
        return np.linalg.det(self.shape_matrices(self.vertices if x is None else x, box)) / 6.0

    def boundary_faces(self) -> np.ndarray:
        """The outer surface: (F, 2) rows [element, k] for the face opposite vertex k that no other element shares.

        Faces are keyed by their vertex ids and their centroid wrapped into the box along the periodic
        axes, so a face on a periodic seam is found shared and, in a box only two cubes wide, two faces
        with the same vertex ids in different images are told apart.
        """
        p = self.element_vertices(self.vertices)
        keys = {}
        for k in range(4):
            loc = [i for i in range(4) if i != k]
            centre = p[:, loc].mean(1)
            per = np.asarray(self.periodic)
            centre[:, per] = np.mod(centre[:, per], self.box[per])
            ids = np.sort(self.tets[:, loc], axis=1)
            for e in range(self.elements):
                key = (*ids[e], *np.round(centre[e] / self.cube_nm * 6).astype(int))
                keys.setdefault(key, []).append((e, k))
        return np.array([v[0] for v in keys.values() if len(v) == 1], dtype=int).reshape(-1, 2)


def block(cubes: tuple[int, int, int], cube_nm: float, periodic: tuple[bool, bool, bool]) -> Mesh:
    """A block of cubes[0] x cubes[1] x cubes[2] cubes of edge ``cube_nm``, six tetrahedra each."""
    n = np.array(cubes)
    nv = np.where(periodic, n, n + 1)               # vertices per axis
    grid = np.stack(np.meshgrid(*[np.arange(k) for k in nv], indexing="ij"), -1).reshape(-1, 3)
    vertices = grid * float(cube_nm)

    def vid(idx):
        return (idx[..., 0] * nv[1] + idx[..., 1]) * nv[2] + idx[..., 2]

    paths = []
    for order in itertools.permutations(range(3)):
        p = [np.zeros(3, int)]
        for a in order:
            p.append(p[-1] + np.eye(3, dtype=int)[a])
        paths.append(np.array(p))
    paths = np.array(paths)                          # (6, 4, 3) corner offsets of each tetrahedron
    cube_idx = np.stack(np.meshgrid(*[np.arange(k) for k in n], indexing="ij"), -1).reshape(-1, 3)
    idx = cube_idx[:, None, None, :] + paths[None]   # (C, 6, 4, 3)
    wrap = np.asarray(periodic) & (idx >= n)
    shift = wrap.astype(float).reshape(-1, 4, 3)
    tets = vid(np.where(wrap, idx - n, idx)).reshape(-1, 4)
    mesh = Mesh(vertices, tets, shift, n * float(cube_nm), tuple(bool(p) for p in periodic), tuple(int(c) for c in cubes),
                float(cube_nm))
    neg = mesh.volumes() < 0                          # positive orientation: swap two vertices
    mesh.tets[neg] = mesh.tets[neg][:, [0, 2, 1, 3]]
    mesh.shift[neg] = mesh.shift[neg][:, [0, 2, 1, 3]]
    return mesh
