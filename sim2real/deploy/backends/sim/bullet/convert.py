"""One MuJoCo model element in pybullet's terms: quaternion order, a geom's collision shape, a
body's inertial frame, and the error for what pybullet cannot hold.

:mod:`sim2real.deploy.backends.sim.bullet.build` assembles these into a robot's multibody.

Geoms: planes, spheres, capsules, cylinders, boxes and meshes (as their convex hulls, like
MuJoCo's; robot-import writes hulls).

Errors: :class:`UnsupportedModelError` names the body, joint or geom pybullet cannot build.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pybullet as pb

from sim2real.robots.errors import Sim2RealError


class UnsupportedModelError(Sim2RealError, ValueError):
    """The MuJoCo model holds something the pybullet world cannot represent."""


_GEOM = mujoco.mjtGeom


def xyzw(q_wxyz: np.ndarray) -> list[float]:
    """MuJoCo's (w, x, y, z) quaternion as pybullet's (x, y, z, w)."""
    return [float(q_wxyz[1]), float(q_wxyz[2]), float(q_wxyz[3]), float(q_wxyz[0])]


def wxyz(q_xyzw) -> np.ndarray:
    """pybullet's (x, y, z, w) quaternion as MuJoCo's (w, x, y, z), shape (4,)."""
    return np.array([q_xyzw[3], q_xyzw[0], q_xyzw[1], q_xyzw[2]], dtype=np.float64)


def quat_to_mat(q_wxyz: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of a unit quaternion (w, x, y, z)."""
    mat = np.empty(9)
    mujoco.mju_quat2Mat(mat, np.asarray(q_wxyz, dtype=np.float64))
    return mat.reshape(3, 3)


def geom_shape(m: mujoco.MjModel, g: int, anchor: np.ndarray, meshdir: Path) -> dict | None:
    """pybullet's collision-shape arguments of geom ``g`` in its body's link frame (the body frame
    moved to the joint ``anchor``), or None for a visual geom. A mesh is written to ``meshdir``
    as an OBJ of the compiled mesh's vertices and faces (MuJoCo collides its convex hull, and so
    does pybullet with a mesh file)."""
    if m.geom_contype[g] == 0 and m.geom_conaffinity[g] == 0:
        return None
    t, size = int(m.geom_type[g]), m.geom_size[g]
    pos = (m.geom_pos[g] - anchor).tolist()
    quat = xyzw(m.geom_quat[g])
    if t == _GEOM.mjGEOM_SPHERE:
        args = dict(shapeType=pb.GEOM_SPHERE, radius=float(size[0]))
    elif t == _GEOM.mjGEOM_CAPSULE:
        args = dict(shapeType=pb.GEOM_CAPSULE, radius=float(size[0]), height=2 * float(size[1]))
    elif t == _GEOM.mjGEOM_CYLINDER:
        args = dict(shapeType=pb.GEOM_CYLINDER, radius=float(size[0]), height=2 * float(size[1]))
    elif t == _GEOM.mjGEOM_BOX:
        args = dict(shapeType=pb.GEOM_BOX, halfExtents=size.tolist())
    elif t == _GEOM.mjGEOM_PLANE:
        args = dict(shapeType=pb.GEOM_PLANE, planeNormal=[0.0, 0.0, 1.0])
    elif t == _GEOM.mjGEOM_MESH:
        args = dict(shapeType=pb.GEOM_MESH, fileName=mesh_obj(m, int(m.geom_dataid[g]), meshdir))
    else:
        raise UnsupportedModelError(
            f"geom '{m.geom(g).name or g}' of body '{m.body(m.geom_bodyid[g]).name}': type "
            f"{_GEOM(t).name} has no pybullet shape here (expected plane, sphere, capsule, "
            "cylinder, box or mesh)"
        )
    return dict(args, pos=pos, quat=quat)


def mesh_obj(m: mujoco.MjModel, mesh: int, meshdir: Path) -> str:
    """Mesh ``mesh`` of the compiled model (its frame: MuJoCo's recentred vertices) as an OBJ file
    in ``meshdir``; its path."""
    path = meshdir / f"mesh{mesh}.obj"
    if not path.exists():
        start, count = int(m.mesh_vertadr[mesh]), int(m.mesh_vertnum[mesh])
        faces = m.mesh_face[m.mesh_faceadr[mesh] : m.mesh_faceadr[mesh] + m.mesh_facenum[mesh]]
        verts = m.mesh_vert[start : start + count].astype(np.float64)
        lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in verts.tolist()]
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
        path.write_text("\n".join(lines) + "\n")
    return str(path)


def collision_shape(client: int, shapes: list[dict]) -> int:
    """One pybullet collision shape (compound when several) of ``shapes``; -1 for none."""
    if not shapes:
        return -1
    if len(shapes) == 1:
        s = dict(shapes[0])
        pos, quat = s.pop("pos"), s.pop("quat")
        return pb.createCollisionShape(
            **s, collisionFramePosition=pos, collisionFrameOrientation=quat, physicsClientId=client
        )
    kinds = [s["shapeType"] for s in shapes]
    return pb.createCollisionShapeArray(
        shapeTypes=kinds,
        radii=[s.get("radius", 0.0) for s in shapes],
        halfExtents=[s.get("halfExtents", [0.0, 0.0, 0.0]) for s in shapes],
        lengths=[s.get("height", 0.0) for s in shapes],
        fileNames=[s.get("fileName", "") for s in shapes],
        planeNormals=[s.get("planeNormal", [0.0, 0.0, 1.0]) for s in shapes],
        collisionFramePositions=[s["pos"] for s in shapes],
        collisionFrameOrientations=[s["quat"] for s in shapes],
        physicsClientId=client,
    )


def inertial_frame(m: mujoco.MjModel, b: int, anchor: np.ndarray) -> tuple[list, list, list]:
    """Body ``b``'s inertial frame position (link frame), orientation (x, y, z, w) and principal
    moments (kg m^2)."""
    return (
        (m.body_ipos[b] - anchor).tolist(),
        xyzw(m.body_iquat[b]),
        np.maximum(m.body_inertia[b], 1e-9).tolist(),
    )


def body_geoms(m: mujoco.MjModel, b: int) -> range:
    """Body ``b``'s geom ids (empty for none: its ``geomadr`` is then -1)."""
    return range(m.body_geomadr[b], m.body_geomadr[b] + m.body_geomnum[b])
