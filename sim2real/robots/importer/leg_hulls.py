"""A leg link's collision hull with fewer vertices, within a tolerance of it (:func:`reduce_hull`).

A leg link's mesh (a thigh, a shank) leans in its link's frame: a capsule fitted to the box around
it in that frame (what the importer wrote before) is far fatter than the mesh, and the guard
counts self-contacts the robot never makes. Its convex hull is the shape MuJoCo collides the
mesh as, but a CAD mesh's hull has hundreds to thousands of vertices, and the guard's distance
query (coal's GJK) costs in proportion. The hull kept here is that of a subset of its vertices,
grown greedily until it reaches within ``HULL_TOLERANCE`` of the full hull in each of
``HULL_DIRECTIONS`` directions spread over the sphere (its support function), then until no
vertex of the mesh's hull lies more than that outside any of its faces (a thin spike no sampled
direction sees): a shape inside the mesh's hull by about that much, with tens of vertices.
"""

from __future__ import annotations

import mujoco
import numpy as np

from sim2real.robots.importer.mjcf_geoms import hull_points
from sim2real.robots.importer.source import compile_built

#: The most a leg hull may fall short of the mesh's hull along any of ``HULL_DIRECTIONS``
#: directions, m (our choice: a fraction of the guard's self-collision margins of centimetres).
HULL_TOLERANCE = 0.002
#: Directions the tolerance is checked in (a Fibonacci lattice: about 6 degrees apart, so that
#: between them a 0.3 m hull falls short by well under a millimetre more).
HULL_DIRECTIONS = 1024


def sphere_directions(n: int) -> np.ndarray:
    """(n, 3) unit vectors spread evenly over the sphere (the Fibonacci lattice)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5.0**0.5) * k
    r = np.sqrt(1.0 - z**2)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def reduced_vertices(points: np.ndarray, tolerance: float = HULL_TOLERANCE) -> np.ndarray:
    """Indices of a subset of ``points`` (k, 3) m whose hull reaches within ``tolerance`` m of
    theirs along every direction of :func:`sphere_directions` (``HULL_DIRECTIONS``): the
    extreme points along a coarse set, then, one at a time, the extreme point along the
    direction the subset falls shortest in."""
    centred = (points - points.mean(axis=0)).astype(np.float32)
    dirs = sphere_directions(HULL_DIRECTIONS).astype(np.float32)
    reach = centred @ dirs.T  # (k, directions)
    full = reach.max(axis=0)
    keep = set(np.argmax(reach[:, :: HULL_DIRECTIONS // 32], axis=0).tolist())
    current = reach[sorted(keep)].max(axis=0)
    while True:
        d = int(np.argmax(full - current))
        if full[d] - current[d] <= tolerance:
            break
        k = int(np.argmax(reach[:, d]))
        keep.add(k)
        current = np.maximum(current, reach[k])
    for _ in range(len(points)):  # the vertices outside the kept hull's faces, worst first
        normals, offsets = _faces(points[sorted(keep)])
        outside = (points @ normals.T - offsets).max(axis=1)
        k = int(np.argmax(outside))
        if outside[k] <= tolerance:
            break
        keep.add(k)
    return np.array(sorted(keep))


def _faces(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The outward unit normals (f, 3) and offsets (f,) m of the faces of the convex hull of
    ``points`` (k, 3), as MuJoCo computes it (qhull, ``mesh_graph``)."""
    spec = mujoco.MjSpec()
    mesh = spec.add_mesh()
    mesh.name = "hull"
    mesh.uservert = points.ravel()
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname="hull")
    model = compile_built(spec)
    graph, adr = model.mesh_graph, int(model.mesh_graphadr[0])
    nv, nf = int(graph[adr]), int(graph[adr + 1])
    start = adr + 2 + 3 * nv + 3 * nf  # face_globalid: indices into ``points``
    face = graph[start : start + 3 * nf].reshape(-1, 3)
    a, b, c = points[face[:, 0]], points[face[:, 1]], points[face[:, 2]]
    normals = np.cross(b - a, c - a)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    offsets = np.einsum("ij,ij->i", normals, a)
    flip = np.sign(offsets - normals @ points.mean(axis=0))  # the centroid lies inside
    return normals * flip[:, None], offsets * flip


def reduce_hull(spec: mujoco.MjSpec, geom, tolerance: float = HULL_TOLERANCE) -> None:
    """Make the inline hull of ``geom`` the hull of :func:`reduced_vertices` of its vertices
    (a new mesh of the same name: a compiled one keeps its old faces)."""
    points = hull_points(spec, geom)
    keep = reduced_vertices(points, tolerance)
    if len(keep) == len(points):
        return
    name = geom.meshname
    spec.delete(spec.mesh(name))
    mesh = spec.add_mesh()
    mesh.name = name
    mesh.uservert = points[keep].ravel()
