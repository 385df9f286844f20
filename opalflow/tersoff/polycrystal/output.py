"""What the polycrystal workflows leave behind besides numbers: meshes ParaView opens, pictures, tables.

``write_vtu``: the elements as a VTK unstructured grid (meshio), each tetrahedron with its own
four points (periodic seams unwrapped), cell data ``orientation_rgb`` (the crystal direction
along z, |Q^T e_z| as a colour), ``stress_GPa`` (9 components, row-major), ``von_mises_GPa``,
``strain`` (9 components, D_e - I symmetrised) and, when given, point data ``velocity_m_s``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from opalflow.store import atomic_path, new_figure, save_figure
from opalflow.tersoff.polycrystal.dynamics import Polycrystal


def orientation_colours(rotations: np.ndarray) -> np.ndarray:
    """RGB per element: |components of the sample z axis in crystal axes| / their largest."""
    d = np.abs(rotations[:, 2, :])            # row 2 of Q = Q^T e_z in crystal coordinates
    return d / d.max(axis=1, keepdims=True)


def von_mises(stress: np.ndarray) -> np.ndarray:
    dev = stress - np.trace(stress, axis1=1, axis2=2)[:, None, None] * np.eye(3) / 3.0
    return np.sqrt(1.5 * np.einsum("eab,eab->e", dev, dev))


def write_vtu(path: Path, pc: Polycrystal, velocity_m_s: np.ndarray | None = None) -> None:
    """The current state of ``pc`` as a .vtu file (written under a temporary name, then renamed)."""
    import meshio
    points = pc.mesh.element_vertices(pc.x, pc.box).reshape(-1, 3)
    cells = [("tetra", np.arange(len(points)).reshape(-1, 4))]
    deformation, _ = pc.deformation()
    strain = 0.5 * (deformation + deformation.transpose(0, 2, 1)) - np.eye(3)
    cell_data = {"orientation_rgb": [orientation_colours(pc.rotations)],
                 "stress_GPa": [pc.stress.reshape(-1, 9)], "von_mises_GPa": [von_mises(pc.stress)],
                 "strain": [strain.reshape(-1, 9)]}
    point_data = {}
    if velocity_m_s is not None:
        point_data["velocity_m_s"] = velocity_m_s[pc.mesh.tets].reshape(-1, 3)
    with atomic_path(path, path.name + ".tmp.vtu") as tmp:
        meshio.write(tmp, meshio.Mesh(points, cells, point_data=point_data, cell_data=cell_data), binary=True)


def plot_mesh(path: Path, pc: Polycrystal, title: str) -> None:
    """Two views of the block's outer faces: coloured by orientation, and by the axial stress sigma_xx."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    import matplotlib
    fig = new_figure(figsize=(11, 5))[0]
    fig.clf()
    mesh = pc.mesh
    faces = mesh.boundary_faces()
    local = np.array([[i for i in range(4) if i != k] for k in range(4)])[faces[:, 1]]      # (F, 3)
    corners = pc.mesh.element_vertices(pc.x, pc.box)
    tri = corners[faces[:, :1], local]                                                     # (F, 3, 3)
    sxx = pc.stress[faces[:, 0], 0, 0]
    norm = matplotlib.colors.Normalize(sxx.min(), sxx.max() if sxx.max() > sxx.min() else sxx.min() + 1)
    cmap = matplotlib.colormaps["coolwarm"]
    for i, (colours, label) in enumerate(((orientation_colours(pc.rotations)[faces[:, 0]], "orientation "
                                           "(crystal direction along z as RGB)"),
                                          (cmap(norm(sxx)), "sigma_xx of the element (GPa)"))):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        ax.add_collection3d(Poly3DCollection(tri, facecolors=colours, edgecolors="k", linewidths=0.1))
        lo, hi = tri.reshape(-1, 3).min(0), tri.reshape(-1, 3).max(0)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_zlim(lo[2], hi[2])
        ax.set_box_aspect(hi - lo)
        ax.set_xlabel("x (nm)")
        ax.set_ylabel("y (nm)")
        ax.set_zlabel("z (nm)")
        ax.set_title(label, fontsize=9)
        if i == 1:
            fig.colorbar(matplotlib.cm.ScalarMappable(norm=norm, cmap=cmap), ax=ax, shrink=0.6, label="GPa")
    fig.suptitle(title)
    save_figure(fig, path)
