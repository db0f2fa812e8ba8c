"""The robot in Foxglove's 3D panel: body transforms (``FrameTransforms``) and geometry (``SceneUpdate``).

``RobotScene`` holds the robot's MJCF model (``robot.mjcf.load_model``). ``transforms(q)`` computes every
body's pose with C MuJoCo forward kinematics and gives it relative to its parent body as one
``foxglove.FrameTransforms`` message: frame ``<prefix><body>`` under ``<prefix><parent body>``, the root
body under ``world`` (the MJCF's world body; the chest is fixed at its origin). ``scene()`` gives the MJCF's
geoms as one ``foxglove.SceneUpdate``: one entity per body, in that body's frame (``frame_locked``, so it
follows the transforms), with boxes, spheres, ellipsoids (scaled spheres), cylinders, capsules (a cylinder
and two spheres) and meshes (triangle lists); planes, height fields and SDFs are not drawn (counted in
``skipped``). The same robot under the prefix ``ref/`` in one translucent colour is the tracking reference's
ghost.

Messages are protobuf bytes from the Foxglove SDK's schemas (``foxglove.messages``), which Foxglove draws
without set-up; ``schema(name)`` gives the MCAP schema record's name, encoding and data.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["GHOST_COLOR", "GHOST_PREFIX", "WORLD_FRAME", "RobotScene", "foxglove_schema"]

WORLD_FRAME = "world"
"""The fixed frame of the transforms (the MJCF's world body; the chest is fixed at its origin)."""
GHOST_PREFIX = "ref/"
"""Frame prefix of the tracking reference's ghost robot."""
GHOST_COLOR = (0.3, 0.75, 1.0, 0.35)
"""RGBA of the ghost robot (translucent light blue), each in [0, 1]."""

# mjtGeom values (mujoco.mjtGeom): stable across MuJoCo 3.x.
_PLANE, _HFIELD, _SPHERE, _CAPSULE, _ELLIPSOID, _CYLINDER, _BOX, _MESH = range(8)


def foxglove_schema(name: str) -> tuple[str, str, bytes]:
    """The MCAP schema of a Foxglove message type (``"FrameTransforms"``): (name, encoding, data).

    ``name`` is the type's name in ``foxglove.messages``; the schema is the SDK's protobuf
    ``FileDescriptorSet`` (schema name ``foxglove.<name>``, encoding ``protobuf``).
    """
    from foxglove import messages

    schema = getattr(messages, name).get_schema()
    return schema.name, schema.encoding, bytes(schema.data)


def _timestamp(stamp_ns: int) -> Any:
    from foxglove.messages import Timestamp

    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    return Timestamp(sec, nsec)


class RobotScene:
    """Forward kinematics and geometry of one MJCF model, as Foxglove 3D messages."""

    def __init__(self, model: Any, joint_names: Sequence[str]) -> None:
        """Bind the model to the log's joint order.

        Args:
            model: ``mujoco.MjModel`` (kept; read only).
            joint_names: the order of the logged joint vectors, shape (n,); each must be a hinge or slide
                joint of the model (the model's other joints stay at ``qpos0``).

        Raises:
            ValueError: a name that is not a joint of the model (the message lists the model's joints).
        """
        import mujoco

        self._mj = mujoco
        self.model = model
        self.data = mujoco.MjData(model)
        valid = [model.joint(i).name for i in range(model.njnt)]
        unknown = [n for n in joint_names if n not in valid]
        if unknown:
            raise ValueError(f"joints {unknown} are not in the robot model; its joints: {valid}")
        self.joint_names = tuple(joint_names)
        self._qadr = np.array([model.jnt_qposadr[valid.index(n)] for n in joint_names], dtype=np.intp)
        self.body_names = tuple(model.body(i).name for i in range(model.nbody))
        self._parent = np.asarray(model.body_parentid)
        self.skipped = 0
        """Geoms that ``scene`` does not draw (planes, height fields, SDFs)."""
        self._entities = self._geometry()

    @classmethod
    def for_mode(cls, mode: str, joint_names: Sequence[str]) -> RobotScene:
        """The Lite's scene for a joint set (``"arms"`` / ``"arms_neck"``; ``robot.mjcf.load_model``)."""
        from bar_policy.robot.mjcf import load_model

        return cls(load_model(mode), joint_names)

    # -- kinematics ---------------------------------------------------------------------------------
    def body_poses(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each body's pose relative to its parent body at joint positions ``q``.

        Args:
            q: joint positions in ``joint_names`` order, rad, shape (n,).

        Returns:
            ``(pos, quat)``: translations, m, shape (nbody, 3), and rotations as unit quaternions (w, x, y,
            z), shape (nbody, 4); row 0 is the world body (identity).
        """
        mj, d = self._mj, self.data
        d.qpos[:] = self.model.qpos0
        d.qpos[self._qadr] = q
        mj.mj_kinematics(self.model, d)
        pos = np.zeros((self.model.nbody, 3))
        quat = np.zeros((self.model.nbody, 4))
        quat[0, 0] = 1.0
        inv = np.zeros(4)
        for b in range(1, self.model.nbody):
            p = self._parent[b]
            mj.mju_negQuat(inv, d.xquat[p])
            mj.mju_rotVecQuat(pos[b], d.xpos[b] - d.xpos[p], inv)
            mj.mju_mulQuat(quat[b], inv, d.xquat[b])
        return pos, quat

    def frame(self, body: int, prefix: str = "") -> str:
        """The frame id of body ``body`` (``world`` for body 0, whatever the prefix)."""
        return WORLD_FRAME if body == 0 else prefix + self.body_names[body]

    def transforms(self, q: np.ndarray, stamp_ns: int, prefix: str = "") -> bytes:
        """``foxglove.FrameTransforms`` of every body but the world at ``q`` (rad, (n,)), protobuf bytes.

        Each transform takes ``<prefix><parent>`` (``world`` for the root) to ``<prefix><body>``, stamped
        ``stamp_ns`` (ns since the epoch).
        """
        from foxglove.messages import FrameTransform, FrameTransforms, Quaternion, Vector3

        pos, quat = self.body_poses(q)
        stamp = _timestamp(stamp_ns)
        out = []
        for b in range(1, self.model.nbody):
            x, y, z = pos[b].tolist()
            w, qx, qy, qz = quat[b].tolist()
            out.append(
                FrameTransform(
                    timestamp=stamp,
                    parent_frame_id=self.frame(int(self._parent[b]), prefix),
                    child_frame_id=self.frame(b, prefix),
                    translation=Vector3(x=x, y=y, z=z),
                    rotation=Quaternion(x=qx, y=qy, z=qz, w=w),
                )
            )
        return FrameTransforms(transforms=out).encode()

    # -- geometry -----------------------------------------------------------------------------------
    def _geometry(self) -> dict[int, list[tuple[str, dict[str, Any]]]]:
        """Body -> [(primitive kind, fields)] with poses in the body frame and the geoms' own colours."""
        m = self.model
        out: dict[int, list[tuple[str, dict[str, Any]]]] = {}
        for g in range(m.ngeom):
            kind, size = int(m.geom_type[g]), np.asarray(m.geom_size[g], dtype=float)
            pos, quat = np.asarray(m.geom_pos[g], dtype=float), np.asarray(m.geom_quat[g], dtype=float)
            rgba = tuple(float(c) for c in m.geom_rgba[g])
            prims: list[tuple[str, dict[str, Any]]] = []
            if kind == _BOX:
                prims.append(("cubes", {"pos": pos, "quat": quat, "size": 2 * size, "rgba": rgba}))
            elif kind in (_SPHERE, _ELLIPSOID):
                diam = 2 * (size[[0, 0, 0]] if kind == _SPHERE else size)
                prims.append(("spheres", {"pos": pos, "quat": quat, "size": diam, "rgba": rgba}))
            elif kind in (_CYLINDER, _CAPSULE):
                r, half = size[0], size[1]
                cyl = np.array([2 * r, 2 * r, 2 * half])
                prims.append(("cylinders", {"pos": pos, "quat": quat, "size": cyl, "rgba": rgba}))
                if kind == _CAPSULE:  # the end caps, on the geom's z axis
                    for sign in (-1.0, 1.0):
                        end = np.zeros(3)
                        self._mj.mju_rotVecQuat(end, np.array([0.0, 0.0, sign * half]), quat)
                        cap = {"pos": pos + end, "quat": quat, "size": np.full(3, 2 * r), "rgba": rgba}
                        prims.append(("spheres", cap))
            elif kind == _MESH:
                mid = int(m.geom_dataid[g])
                v0, nv = int(m.mesh_vertadr[mid]), int(m.mesh_vertnum[mid])
                f0, nf = int(m.mesh_faceadr[mid]), int(m.mesh_facenum[mid])
                verts = np.asarray(m.mesh_vert[v0 : v0 + nv], dtype=float)
                faces = np.asarray(m.mesh_face[f0 : f0 + nf], dtype=np.int64)
                tri = {"pos": pos, "quat": quat, "points": verts[faces.reshape(-1)], "rgba": rgba}
                prims.append(("triangles", tri))
            else:
                self.skipped += 1
            if prims:
                out.setdefault(int(m.geom_bodyid[g]), []).extend(prims)
        return out

    def scene(self, stamp_ns: int, prefix: str = "", color: tuple[float, ...] | None = None) -> bytes:
        """``foxglove.SceneUpdate`` of the model's geoms, one entity per body, protobuf bytes.

        Args:
            stamp_ns: entity timestamp, ns since the epoch.
            prefix: frame and entity id prefix (``GHOST_PREFIX`` for the reference).
            color: RGBA for every primitive (the ghost); None keeps each geom's ``rgba``.
        """
        from foxglove.messages import (
            Color,
            CubePrimitive,
            CylinderPrimitive,
            Point3,
            Pose,
            Quaternion,
            SceneEntity,
            SceneUpdate,
            SpherePrimitive,
            TriangleListPrimitive,
            Vector3,
        )

        def pose(p: dict[str, Any]) -> Pose:
            (x, y, z), (w, qx, qy, qz) = p["pos"].tolist(), p["quat"].tolist()
            return Pose(position=Vector3(x=x, y=y, z=z), orientation=Quaternion(x=qx, y=qy, z=qz, w=w))

        def rgba(p: dict[str, Any]) -> Color:
            r, g, b, a = color if color is not None else p["rgba"]
            return Color(r=r, g=g, b=b, a=a)

        def vec(v: np.ndarray) -> Vector3:
            x, y, z = v.tolist()
            return Vector3(x=x, y=y, z=z)

        stamp = _timestamp(stamp_ns)
        entities = []
        for body, prims in self._entities.items():
            kinds: dict[str, list[Any]] = {"cubes": [], "spheres": [], "cylinders": [], "triangles": []}
            for kind, p in prims:
                if kind == "cubes":
                    kinds[kind].append(CubePrimitive(pose=pose(p), size=vec(p["size"]), color=rgba(p)))
                elif kind == "spheres":
                    kinds[kind].append(SpherePrimitive(pose=pose(p), size=vec(p["size"]), color=rgba(p)))
                elif kind == "cylinders":
                    kinds[kind].append(
                        CylinderPrimitive(
                            pose=pose(p), size=vec(p["size"]), bottom_scale=1.0, top_scale=1.0, color=rgba(p)
                        )
                    )
                else:
                    points = [Point3(x=x, y=y, z=z) for x, y, z in p["points"].tolist()]
                    kinds[kind].append(TriangleListPrimitive(pose=pose(p), points=points, color=rgba(p)))
            frame = self.frame(body, prefix)
            entities.append(
                SceneEntity(timestamp=stamp, frame_id=frame, id=frame, frame_locked=True, **kinds)
            )
        return SceneUpdate(entities=entities).encode()
