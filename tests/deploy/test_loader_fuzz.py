"""Property-based fuzz of every loader: any input gives a valid result or the project's ``InputError``.

Random bytes, random JSON-like structures (with NaN, infinities, huge numbers, odd keys) and nesting far
deeper than the interpreter's recursion limit (built directly, not by hypothesis' recursion) go to the
policy metadata parser, the ONNX policy loader, the motion clip loaders (NPZ, CSV), the commands-file
loaders (JSON, CSV, NPZ) and stream messages, the calibration loader, the run-log loader and the CAN
reply decoder. Anything but ``InputError`` (a ``RecursionError``, ``EOFError``, ``BadZipFile``, a bare
``TypeError``, ...) fails the test.
"""

from __future__ import annotations

import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from policy_factory import default_metadata, make_policy_file

from bar_policy._files import InputError
from bar_policy.deploy.log.read import load_log
from bar_policy.deploy.metadata import PolicyMetadata
from bar_policy.deploy.policy import load_policy
from bar_policy.motion.clip import Clip, load_clip, load_csv, save_clip
from bar_policy.robstride.calibration import Calibration
from bar_policy.robstride.errors import FrameError
from bar_policy.robstride.protocol import decode_reply
from bar_policy.tasks.reach.commands import FileCommands, StreamCommands

FAST = settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
"""Loaders that take a millisecond or less."""
SLOW = settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
"""Loaders that build an ONNX session per example."""
NAMES = ("target_pos_left", "target_pos_right")
VALID_PROPS = default_metadata().to_props()

# -- strategies ---------------------------------------------------------------------------------------
scalars = (
    st.none()
    | st.booleans()
    | st.integers(min_value=-(10**30), max_value=10**30)
    | st.sampled_from([10**400, -(10**400)])
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=20)
)
json_like = st.recursive(
    scalars,
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=10), inner, max_size=5),
    max_leaves=25,
)


def _deep_text(depth: int, kind: str) -> str:
    """JSON text nested ``depth`` levels (lists, objects or both), built without recursion."""
    if kind == "list":
        return "[" * depth + "1" + "]" * depth
    if kind == "dict":
        return '{"a": ' * depth + "1" + "}" * depth
    return '[{"a": ' * (depth // 2) + "1" + "}]" * (depth // 2)


deep_json = st.builds(_deep_text, st.integers(1001, 4000), st.sampled_from(["list", "dict", "mixed"]))
json_text = (
    json_like.map(json.dumps)  # NaN / Infinity tokens included
    | deep_json
    | st.text(max_size=60)
    | st.binary(max_size=60).map(lambda b: b.decode("latin-1"))
)
"""Text a JSON loader may be handed."""
deep_structure = st.builds(
    lambda d, kind: json.loads(_deep_text(d, kind)), st.integers(100, 900), st.sampled_from(["list", "dict"])
)
"""Parsed values nested deeper than any project file (built directly; json.loads handles < 1000)."""


def _accept(call: Any, *args: Any, **kwargs: Any) -> Any:
    """``call(*args)``; an ``InputError`` is accepted (returns None), anything else propagates."""
    try:
        return call(*args, **kwargs)
    except InputError:
        return None


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A directory the examples overwrite (hypothesis runs many examples per test function)."""
    return tmp_path_factory.mktemp("fuzz")


# -- policy metadata ------------------------------------------------------------------------------------
@FAST
@given(
    st.dictionaries(
        st.sampled_from([*sorted(VALID_PROPS), "bar.provenance", "bar.action_filter"]), json_text
    ),
    st.lists(st.sampled_from(sorted(VALID_PROPS)), max_size=2),
)
def test_metadata_props(changes: dict[str, str], dropped: list[str]) -> None:
    props = VALID_PROPS | changes
    for k in dropped:
        props.pop(k, None)
    meta = _accept(PolicyMetadata.from_props, props)
    assert meta is None or isinstance(meta, PolicyMetadata)


@FAST
@given(st.sampled_from(["bar.randomization", "bar.obs_schema", "bar.training", "bar.provenance"]), deep_json)
def test_metadata_deep_nesting(key: str, text: str) -> None:
    meta = _accept(PolicyMetadata.from_props, VALID_PROPS | {key: text})
    assert meta is None or "error" in meta.provenance  # provenance informs: never refuses


@FAST
@given(st.dictionaries(st.sampled_from(sorted(VALID_PROPS)), st.text(max_size=40), min_size=1))
def test_hc_only_props(changes: dict[str, str]) -> None:
    props = {k: v for k, v in (VALID_PROPS | changes).items() if not k.startswith("bar.")}
    _accept(PolicyMetadata.from_props, props)


@SLOW
@given(st.binary(max_size=300))
def test_policy_file_random_bytes(work: Path, data: bytes) -> None:
    path = work / "random.onnx"
    path.write_bytes(data)
    assert _accept(load_policy, path) is None


@SLOW
@given(st.sampled_from(["bar.randomization", "bar.obs_schema", "bar.action_clip", "bar.task"]), json_text)
def test_policy_file_metadata(work: Path, key: str, text: str) -> None:
    path = make_policy_file(work / "meta.onnx", props={key: text})
    _accept(load_policy, path)


# -- motion clips -------------------------------------------------------------------------------------
@FAST
@given(st.binary(max_size=400))
def test_clip_random_bytes(work: Path, data: bytes) -> None:
    (work / "clip.npz").write_bytes(data)
    (work / "clip.csv").write_bytes(data)
    assert _accept(load_clip, work / "clip.npz") is None
    _accept(load_csv, work / "clip.csv", rate_hz=50.0)


arrays = st.one_of(
    hnp.arrays(
        hnp.scalar_dtypes() | hnp.unicode_string_dtypes() | hnp.byte_string_dtypes(),
        hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=4),
    ),
    st.builds(lambda n: np.zeros((n, 14), np.float32), st.integers(0, 4)),
    st.just(np.array("bar_policy.motion/1")),
)
CLIP_KEYS = ["format", "name", "rate_hz", "joint_names", "joint_pos", "content_hash", "x"]


@FAST
@given(st.dictionaries(st.sampled_from(CLIP_KEYS), arrays), st.lists(st.sampled_from(CLIP_KEYS), max_size=2))
def test_clip_random_npz(work: Path, changes: dict[str, np.ndarray], dropped: list[str]) -> None:
    valid = work / "valid.npz"
    if not valid.exists():
        save_clip(Clip.make("c", 50.0, np.zeros((3, 14))), valid)
    with np.load(valid) as z:
        content = {k: z[k] for k in z.files if k not in dropped}
    path = work / "mutated.npz"
    with path.open("wb") as f:
        np.savez(f, **(content | changes))
    clip = _accept(load_clip, path)
    assert clip is None or isinstance(clip, Clip)


@FAST
@given(st.lists(st.lists(st.text(max_size=8) | st.floats().map(str), max_size=16), max_size=6))
def test_clip_random_csv(work: Path, rows: list[list[str]]) -> None:
    joints = Clip.make("c", 50.0, np.zeros((2, 14))).joint_names
    path = work / "rows.csv"
    path.write_text("\n".join(",".join(r) for r in [list(joints), *rows]))
    _accept(load_csv, path, rate_hz=50.0)


# -- commands files and stream messages -----------------------------------------------------------------
@FAST
@given(st.sampled_from([".json", ".csv", ".npz"]), st.binary(max_size=300))
def test_commands_random_bytes(work: Path, suffix: str, data: bytes) -> None:
    path = work / f"cmd{suffix}"
    path.write_bytes(data)
    _accept(FileCommands, NAMES, path)


@FAST
@given(json_text | json_like.map(lambda v: json.dumps({"commands": [{"t": 0, NAMES[0]: v, NAMES[1]: v}]})))
def test_commands_json(work: Path, text: str) -> None:
    path = work / "cmd.json"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    source = _accept(FileCommands, NAMES, path)
    if source is not None:
        assert all(np.isfinite(v).all() for v in source(0.0).values())


@FAST
@given(st.lists(json_text, max_size=5))
def test_stream_messages_never_raise(lines: list[str]) -> None:
    initial = {n: np.zeros(3) for n in NAMES}
    source = StreamCommands(NAMES, initial, stdin=io.StringIO(""))
    try:
        for line in lines:
            source._apply(line)  # a bad message is counted and logged, never raised
        assert source.bad_messages + source.messages == len(lines)
        assert all(np.isfinite(v).all() for v in source(0.0).values())
    finally:
        source.close()


# -- calibration ----------------------------------------------------------------------------------------
@FAST
@given(
    json_text
    | st.binary(max_size=100)
    | json_like.map(lambda v: json.dumps({"joints": {"j": v}}))
    | json_like.map(lambda v: json.dumps({"joints": {"j": {"id": v, "direction": 1, "homing_offset": v}}}))
)
def test_calibration(work: Path, data: str | bytes) -> None:
    path = work / "calibration.json"
    path.write_bytes(data if isinstance(data, bytes) else data.encode("utf-8", "surrogatepass"))
    cal = _accept(Calibration.load, path)
    if cal is not None:
        assert all(math.isfinite(j.homing_offset) for j in cal.joints.values())


# -- run logs -------------------------------------------------------------------------------------------
@FAST
@given(st.sampled_from(["log.npz", "run.mcap"]), st.binary(max_size=300), json_text)
def test_run_log_random_bytes(work: Path, name: str, data: bytes, run_json: str) -> None:
    run = work / "run"
    run.mkdir(exist_ok=True)
    for f in run.iterdir():
        f.unlink()
    (run / name).write_bytes(data)
    (run / "run.json").write_text(run_json, encoding="utf-8", errors="surrogatepass")
    assert _accept(load_log, run / name) is None
    _accept(load_log, run)


@FAST
@given(json_text | deep_json)
def test_run_log_meta_json(work: Path, meta_json: str) -> None:
    path = work / "meta.npz"
    np.savez(path, meta_json=np.array(meta_json), t=np.zeros(3))
    result = _accept(load_log, path)
    assert result is None or isinstance(result[1], dict)


# -- CAN frames -----------------------------------------------------------------------------------------
@FAST
@given(
    st.integers(min_value=-1, max_value=2**30) | st.none() | st.text(max_size=3),
    st.binary(max_size=12) | st.text(max_size=8) | st.none(),
    st.booleans(),
)
def test_can_reply_decoding(arbitration_id: Any, data: Any, extended: bool) -> None:
    try:
        decode_reply(arbitration_id, data, is_extended_id=extended, models={1: "RS02"})
    except FrameError as e:
        assert isinstance(e, InputError)
