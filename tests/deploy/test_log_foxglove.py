"""The run log in the field's formats: every channel of a sim-target tracking run read back with a
schema-aware decoder (``mcap_ros2`` for the ROS 2 joint states, protobuf descriptors from the schema
records for the Foxglove messages, JSON Schema for the project's topics) and checked against the NPZ arrays
and C MuJoCo; the CDR bytes against ``mcap_ros2``'s own writer; the live server's channels."""

from __future__ import annotations

import io
import json
import logging
import math
import time

import mujoco
import numpy as np
import pytest
from policy_factory import default_metadata, make_policy_file

from bar_policy.deploy.log.foxglove_scene import GHOST_COLOR, RobotScene
from bar_policy.deploy.log.live import LiveServer
from bar_policy.deploy.log.mcap_schema import MCAP_FILE, OPTIONAL_TICK_TOPICS, TICK_TOPICS, TRANSITION_TOPIC
from bar_policy.deploy.log.mcap_write import MODEL_ATTACHMENT
from bar_policy.deploy.log.read import load_log
from bar_policy.deploy.log.ros2_schema import JOINT_STATE_SCHEMA, JOINT_STATE_TYPE, encode_joint_state
from bar_policy.deploy.policy import load_policy
from bar_policy.deploy.runtime import Runtime, RuntimeConfig
from bar_policy.deploy.safety import SafetyConfig
from bar_policy.deploy.targets.sim import SimTarget
from bar_policy.motion import Clip
from bar_policy.robot.constants import load_robot
from bar_policy.robot.mjcf import lite_xml, load_model
from bar_policy.tasks.track.deploy import reference_for

mcap_ros2 = pytest.importorskip("mcap_ros2")
pytest.importorskip("foxglove")

ROBOT = load_robot("arms")
PIANO = ROBOT.pose("piano_ready")
FRAMES = [PIANO + 0.05 * k for k in range(4)]
"""A 4-frame clip at 50 Hz, piano_ready + 0.05 k rad on every joint."""
WELL_KNOWN = {
    "/joint_states": ("sensor_msgs/msg/JointState", "ros2msg", "cdr"),
    "/joint_commands": ("sensor_msgs/msg/JointState", "ros2msg", "cdr"),
    "/reference/joint_states": ("sensor_msgs/msg/JointState", "ros2msg", "cdr"),
    "/tf": ("foxglove.FrameTransforms", "protobuf", "protobuf"),
    "/reference/tf": ("foxglove.FrameTransforms", "protobuf", "protobuf"),
    "/robot/scene": ("foxglove.SceneUpdate", "protobuf", "protobuf"),
    "/reference/scene": ("foxglove.SceneUpdate", "protobuf", "protobuf"),
    "/log": ("foxglove.Log", "protobuf", "protobuf"),
}


def _proto_class(schema):
    """The protobuf message class that a ``protobuf`` schema record (a FileDescriptorSet) describes."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    pool = descriptor_pool.DescriptorPool()
    files = list(descriptor_pb2.FileDescriptorSet.FromString(schema.data).file)
    while files:  # dependencies first, whatever the set's order
        for fd in list(files):
            if all(pool_has(pool, dep) for dep in fd.dependency):
                pool.Add(fd)
                files.remove(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))


def pool_has(pool, name):
    try:
        pool.FindFileByName(name)
    except KeyError:
        return False
    return True


def _decode_all(path):
    """Topic -> [(log_time, decoded message)] for every channel; the schemas seen per topic."""
    import jsonschema
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    ros2 = DecoderFactory()
    out, schemas, decoders = {}, {}, {}
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        attachments = {a.name: a.data for a in reader.iter_attachments()}
        for schema, channel, message in reader.iter_messages():
            schemas[channel.topic] = (schema.name, schema.encoding, channel.message_encoding)
            if schema.id not in decoders:
                if schema.encoding == "ros2msg":
                    decoders[schema.id] = ros2.decoder_for(channel.message_encoding, schema)
                elif schema.encoding == "protobuf":
                    cls = _proto_class(schema)
                    decoders[schema.id] = cls.FromString
                else:
                    assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
                    validator = jsonschema.Draft202012Validator(json.loads(schema.data))

                    def decode(data, validator=validator):
                        body = json.loads(data)
                        validator.validate(body)
                        return body

                    decoders[schema.id] = decode
            out.setdefault(channel.topic, []).append((message.log_time, decoders[schema.id](message.data)))
    topics = {ch.topic for ch in summary.channels.values()}
    return out, schemas, topics, attachments


def _run_sim_track(tmp_path, **kwargs):
    policy = load_policy(
        make_policy_file(tmp_path / "track.onnx", metadata=default_metadata(task="track"), bias=0.1)
    )
    ref = reference_for(policy, Clip.make("tiny", 50.0, np.array(FRAMES)))
    config = RuntimeConfig(duration=None, safety=SafetyConfig(ramp_time=0.04), end_hold=0.1)
    rt = Runtime(policy, SimTarget("arms"), ref, config, log_dir=tmp_path / "runs", **kwargs)
    return rt


def _world_pose(transforms, child, prefix=""):
    """A frame's position and rotation in ``world``, composed along the parent chain of ``transforms``."""
    by_child = {t.child_frame_id: t for t in transforms}
    pos, rot = np.zeros(3), np.eye(3)
    chain = []
    frame = prefix + child
    while frame != "world":
        t = by_child[frame]
        chain.append(t)
        frame = t.parent_frame_id
    for t in reversed(chain):  # world -> ... -> child
        r = np.zeros(9)
        mujoco.mju_quat2Mat(r, np.array([t.rotation.w, t.rotation.x, t.rotation.y, t.rotation.z]))
        pos = pos + rot @ np.array([t.translation.x, t.translation.y, t.translation.z])
        rot = rot @ r.reshape(3, 3)
    return pos, rot


def test_sim_log_reads_back_every_channel_with_a_schema_aware_decoder(tmp_path, caplog):
    # The mode changes are INFO records of this logger (``bar-deploy eval`` quietens it in its process).
    caplog.set_level(logging.INFO, logger="bar_policy.deploy.safety")
    rt = _run_sim_track(tmp_path)
    res = rt.run()
    arrays, meta = load_log(res.log_path)
    path = res.log_path.parent / MCAP_FILE
    msgs, schemas, topics, attachments = _decode_all(path)
    n = arrays["t"].size
    assert n == 11  # 2 HOLD ticks, 4 frames, 5 ticks of end hold (1 + 0.1 s / 0.02 s)
    json_topics = {*TICK_TOPICS, *OPTIONAL_TICK_TOPICS, TRANSITION_TOPIC}
    assert topics == json_topics | set(WELL_KNOWN)  # every channel has messages and was decoded
    assert set(msgs) == topics
    for topic, expected in WELL_KNOWN.items():
        assert schemas[topic] == expected, topic

    # The robot's model rides along as an attachment.
    assert attachments[MODEL_ATTACHMENT].decode() == lite_xml("arms")

    # Joint states: names in the canonical order, the logged float64 values exactly, stamp = log time.
    start_ns = round(meta["started_unix"] * 1e9)
    for topic, keys in (
        ("/joint_states", ("q", "dq", "tau")),
        ("/joint_commands", ("q_cmd", "dq_cmd", "tau_cmd")),
        ("/reference/joint_states", ("ref_q", None, None)),
    ):
        assert len(msgs[topic]) == n, topic
        for k, (log_time, m) in enumerate(msgs[topic]):
            assert m.name == list(ROBOT.joint_names)
            assert m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == log_time
            assert abs(log_time - (start_ns + round(arrays["t"][k] * 1e9))) < 1000
            for field, key in zip(("position", "velocity", "effort"), keys, strict=True):
                got = np.array(getattr(m, field))
                if key is None:
                    assert got.size == 0
                else:
                    np.testing.assert_array_equal(got, arrays[key][k], err_msg=f"{topic} {field} {k}")
    # The same through the ROS 2 MCAP reader (mcap's reader with mcap_ros2's decoders: by the schema alone).
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        ros = [m for *_, m in reader.iter_decoded_messages(topics=["/joint_states"])]
    np.testing.assert_array_equal([m.position for m in ros], arrays["q"])

    # Transforms: the measured robot and the reference's ghost, each body composed to world equals C MuJoCo.
    model = load_model("arms")
    data = mujoco.MjData(model)
    bodies = [model.body(i).name for i in range(1, model.nbody)]
    for topic, key, prefix in (("/tf", "q", ""), ("/reference/tf", "ref_q", "ref/")):
        assert len(msgs[topic]) == n
        for k in (0, n // 2, n - 1):
            transforms = msgs[topic][k][1].transforms
            assert [t.child_frame_id for t in transforms] == [prefix + b for b in bodies]
            data.qpos[:] = arrays[key][k]  # the model's joints are the canonical order
            mujoco.mj_kinematics(model, data)
            for b in ("chest", "left_hand", "right_elbow_pitch", "head"):
                pos, rot = _world_pose(transforms, b, prefix)
                np.testing.assert_allclose(pos, data.body(b).xpos, atol=1e-12)
                np.testing.assert_allclose(rot, data.body(b).xmat.reshape(3, 3), atol=1e-12)
    # Scenes: one entity per body with geoms, primitives from the MJCF's geoms (capsule = cylinder + 2
    # spheres; the floor plane is not drawn), the ghost in translucent light blue.
    types = model.geom_type
    cap, box = mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_BOX
    scene = msgs["/robot/scene"][0][1]
    assert len(msgs["/robot/scene"]) == len(msgs["/reference/scene"]) == 1  # 0.2 s < SCENE_PERIOD
    assert sum(len(e.cylinders) for e in scene.entities) == int((types == cap).sum())
    assert sum(len(e.spheres) for e in scene.entities) == 2 * int((types == cap).sum())
    assert sum(len(e.cubes) for e in scene.entities) == int((types == box).sum())
    drawn = {model.body(int(model.geom_bodyid[g])).name for g in range(model.ngeom) if types[g] != 0}
    assert {e.frame_id for e in scene.entities} == drawn and all(e.frame_locked for e in scene.entities)
    g = next(g for g in range(model.ngeom) if types[g] == cap)
    ent = next(e for e in scene.entities if e.frame_id == model.body(int(model.geom_bodyid[g])).name)
    r, half = model.geom_size[g][:2]
    cyl = ent.cylinders[0]
    assert (cyl.size.x, cyl.size.y, cyl.size.z) == pytest.approx((2 * r, 2 * r, 2 * half))
    ghost = msgs["/reference/scene"][0][1]
    assert {e.frame_id for e in ghost.entities} == {"ref/" + b for b in drawn}
    colors = {(c.color.r, c.color.g, c.color.b, c.color.a) for e in ghost.entities for c in e.cylinders}
    assert len(colors) == 1 and colors.pop() == pytest.approx(GHOST_COLOR)

    # Log lines: the mode changes the safety supervisor logged, as foxglove.Log at INFO (level 2).
    lines = [m for _, m in msgs["/log"]]
    for tr in meta["transitions"]:
        assert any(f"mode {tr['from']} -> {tr['to']}" in m.message and m.level == 2 for m in lines), tr
    assert all(m.name.startswith("bar_policy") and m.file.endswith(".py") and m.line > 0 for m in lines)


def test_joint_state_bytes_equal_the_ros2_mcap_writers():
    """The hand-written CDR equals what ``mcap_ros2.writer`` encodes for the same message, NaN included."""
    from mcap.reader import make_reader
    from mcap_ros2.writer import Writer

    names = ["a", "bc", "def"]
    q, tau = [0.5, -1.25, math.nan], [1.0, 2.0, -3.5]
    stamp = 1_700_000_000_123_456_789
    buf = io.BytesIO()
    w = Writer(buf)
    schema = w.register_msgdef(JOINT_STATE_TYPE, JOINT_STATE_SCHEMA)
    header = {"stamp": {"sec": 1_700_000_000, "nanosec": 123_456_789}, "frame_id": ""}
    w.write_message(
        "/j", schema, {"header": header, "name": names, "position": q, "velocity": [], "effort": tau}
    )
    w.finish()
    buf.seek(0)
    ((_, _, message),) = make_reader(buf).iter_messages()
    assert encode_joint_state(stamp, names, q, (), tau) == message.data


def test_scene_draws_meshes_and_counts_what_it_skips():
    """A model with a mesh, an ellipsoid and a plane: a triangle list of the mesh's faces, a scaled sphere."""
    xml = """<mujoco><asset><mesh name="tet" vertex="0 0 0  1 0 0  0 1 0  0 0 1"/></asset>
    <worldbody><geom type="plane" size="1 1 0.1"/>
      <body name="b"><joint name="j" type="hinge"/><geom type="mesh" mesh="tet"/>
        <geom type="ellipsoid" size="0.1 0.2 0.3" pos="0 0 1"/></body></worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    scene = RobotScene(model, ["j"])
    assert scene.skipped == 1  # the plane
    from foxglove.messages import SceneUpdate

    cls = _proto_class(SceneUpdate.get_schema())
    (ent,) = cls.FromString(scene.scene(0)).entities
    assert ent.frame_id == "b" and len(ent.triangles) == 1 and len(ent.spheres) == 1
    assert len(ent.triangles[0].points) == 3 * model.mesh_facenum[0]  # 4 faces of a tetrahedron
    s = ent.spheres[0].size
    assert (s.x, s.y, s.z) == pytest.approx((0.2, 0.4, 0.6))
    with pytest.raises(ValueError, match="not in the robot model"):
        RobotScene(model, ["nope"])


def test_live_server_serves_the_log_channels_on_localhost(tmp_path):
    """``--live``: the run log's channels advertised on 127.0.0.1, joint states streamed as CDR."""
    from mcap_ros2._dynamic import generate_dynamic
    from websockets.sync.client import connect

    live = LiveServer(0)
    try:
        assert live.port > 0
        rt = _run_sim_track(tmp_path, live=live)
        rt.open_log()
        with connect(f"ws://127.0.0.1:{live.port}", subprotocols=["foxglove.sdk.v1"]) as ws:
            advertised = {}
            deadline = time.monotonic() + 10
            while "/joint_states" not in advertised and time.monotonic() < deadline:
                msg = json.loads(ws.recv(timeout=5))
                if msg["op"] == "advertise":
                    advertised |= {c["topic"]: c for c in msg["channels"]}
            js = advertised["/joint_states"]
            assert js["encoding"] == "cdr" and js["schemaName"] == JOINT_STATE_TYPE
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": js["id"]}]}))
            time.sleep(1.0)  # the server takes the subscription before the run (the protocol has no ack)
            res = rt.run()
            data = ws.recv(timeout=5)
        with (res.log_path.parent / MCAP_FILE).open("rb") as f:
            from mcap.reader import make_reader

            file_topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
        assert set(advertised) == file_topics
        # Binary message data: opcode 1, subscription id (u32), log time (u64), then the CDR message.
        assert data[0] == 1 and int.from_bytes(data[1:5], "little") == 7
        decode = generate_dynamic(JOINT_STATE_TYPE, JOINT_STATE_SCHEMA)[JOINT_STATE_TYPE]
        arrays, meta = load_log(res.log_path)
        first = decode(data[13:])
        assert first.name == list(ROBOT.joint_names)
        stamp = first.header.stamp.sec * 10**9 + first.header.stamp.nanosec
        assert stamp == int.from_bytes(data[5:13], "little")  # the message's log time, as in the file
        ticks = np.round(meta["started_unix"] * 1e9 + arrays["t"] * 1e9)
        (k,) = np.flatnonzero(np.abs(ticks - stamp) < 1000)  # the tick it belongs to (the first, normally)
        np.testing.assert_array_equal(first.position, arrays["q"][k])
    finally:
        live.stop()


def test_shipped_layout_has_a_3d_panel_a_joint_position_plot_and_a_log_panel():
    """``docs/foxglove_layout.json`` (Foxglove's layout file: ``configById`` + the split tree) names only
    channels the log writes: the robot and ghost scenes, ``/joint_states.position[i]`` per joint, ``/log``."""
    from pathlib import Path

    from bar_policy.deploy.log.channels import WELL_KNOWN_TOPICS

    layout = json.loads((Path(__file__).parents[2] / "docs" / "foxglove_layout.json").read_text())
    panels = layout["configById"]

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    assert sorted(leaves(layout["layout"])) == sorted(panels)
    kinds = {key.split("!")[0]: cfg for key, cfg in panels.items()}
    assert set(kinds) == {"3D", "Plot", "RosOut"}  # RosOut is the id of Foxglove's Log panel
    assert kinds["3D"]["followTf"] == "world"
    assert set(kinds["3D"]["topics"]) == {"/robot/scene", "/reference/scene"} <= set(WELL_KNOWN_TOPICS)
    series = kinds["Plot"]["paths"]
    assert [s["value"] for s in series] == [f"/joint_states.position[{i}]" for i in range(14)]
    assert [s["label"] for s in series] == list(ROBOT.joint_names)
    assert kinds["RosOut"]["topicToRender"] == "/log"
