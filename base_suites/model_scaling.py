"""Uniform scaling of one body subtree of a compiled MuJoCo model, in place.

LIBERO builds its objects from fixed XML assets, so a resized object (LIBERO-PRO's object axis changes
size) is made after compilation: every length of the subtree scales by s about the root body's origin
(geom sizes, offsets, bounding spheres and boxes, mesh vertices and their bounding-volume trees, child
body and site positions, site sizes), mass by s³ and rotational inertia by s⁵ (uniform density). Meshes
must belong to the subtree alone, or another body would change with it.
"""

from __future__ import annotations

import numpy as np


def subtree_bodies(model, root: int) -> list[int]:
    """The body `root` and every body below it."""
    found = []
    for body in range(model.nbody):
        b = body
        while b > 0 and b != root:
            b = model.body_parentid[b]
        if b == root:
            found.append(body)
    return found


def scale_subtree(model, data, root: int, factor: float) -> None:
    """Scale body `root`'s subtree by `factor` and recompute the model's derived constants."""
    import mujoco

    s = float(factor)
    if not s > 0:
        raise ValueError(f"scale factor must be > 0, got {factor!r}")
    bodies = subtree_bodies(model, root)
    inside = np.zeros(model.nbody, dtype=bool)
    inside[bodies] = True
    geoms = np.flatnonzero(inside[model.geom_bodyid])
    meshes = _own_meshes(model, geoms, inside)

    model.geom_size[geoms] *= s
    model.geom_pos[geoms] *= s
    model.geom_rbound[geoms] *= s
    model.geom_aabb[geoms] *= s  # centre and half sizes, in the geom's frame
    children = [b for b in bodies if b != root]
    model.body_pos[children] *= s
    model.body_ipos[bodies] *= s
    model.body_mass[bodies] *= s**3
    model.body_inertia[bodies] *= s**5
    for body in bodies:
        _scale_bvh(model, model.body_bvhadr[body], model.body_bvhnum[body], s)
    sites = np.flatnonzero(inside[model.site_bodyid])
    model.site_pos[sites] *= s
    model.site_size[sites] *= s
    for mesh in meshes:
        start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
        model.mesh_vert[start : start + count] *= s
        _scale_bvh(model, model.mesh_bvhadr[mesh], model.mesh_bvhnum[mesh], s)
        if hasattr(model, "mesh_octnum") and model.mesh_octnum[mesh] > 0:  # 2.3 has no mesh octrees
            start, count = model.mesh_octadr[mesh], model.mesh_octnum[mesh]
            model.oct_aabb[start : start + count] *= s
    mujoco.mj_setConst(model, data)


def _own_meshes(model, geoms: np.ndarray, inside: np.ndarray) -> list[int]:
    import mujoco

    mesh_type = int(mujoco.mjtGeom.mjGEOM_MESH)
    meshes = {int(model.geom_dataid[g]) for g in geoms if model.geom_type[g] == mesh_type}
    for g in range(model.ngeom):
        if model.geom_type[g] == mesh_type and int(model.geom_dataid[g]) in meshes and not inside[model.geom_bodyid[g]]:
            name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_MESH, int(model.geom_dataid[g]))
            raise ValueError(f"mesh {name!r} is shared with a body outside the subtree; it cannot be scaled alone")
    return sorted(meshes)


def _scale_bvh(model, start: int, count: int, s: float) -> None:
    if start >= 0 and count > 0:
        model.bvh_aabb[start : start + count] *= s
