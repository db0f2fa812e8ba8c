"""A policy's ONNX file: its bytes (never a pickle), the onnxruntime session, its metadata, its graph I/O.

Only onnxruntime is used (never pickle, never the ``onnx`` package: the robot computer only has
onnxruntime). Every refusal is a ``PolicyLoadError`` (an ``_files.InputError``) naming the file and the
problem, whatever the bytes or the metadata hold; values it echoes are cut to ``_files.ECHO_LIMIT``
characters.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

from bar_policy._files import loads_json, shorten
from bar_policy.deploy.contract import refuse
from bar_policy.deploy.metadata import MetadataError, PolicyMetadata

__all__ = [
    "ACTION_CLIP_KEY",
    "DEFAULT_ACTION_CLIP",
    "action_clip",
    "check_io",
    "metadata",
    "read_bytes",
    "session",
]

ACTION_CLIP_KEY = "bar.action_clip"
"""Optional metadata key: symmetric bound applied to raw actions (JSON number > 0, or null for none)."""
DEFAULT_ACTION_CLIP = 1.0
"""Action bound when the file has no ``bar.action_clip`` (the LiteReach contract: actions in [-1, 1])."""

_PICKLE_SUFFIXES = (".pt", ".pth", ".pkl", ".pickle", ".ckpt", ".joblib")


def read_bytes(path: Path) -> bytes:
    """The file's bytes, after refusing pickles by suffix and by magic number."""
    if path.suffix.lower() in _PICKLE_SUFFIXES:
        raise refuse(path, f"{path.suffix} files are pickles; only ONNX files are loaded (export to .onnx)")
    try:
        data = path.read_bytes()
    except OSError as e:
        raise refuse(path, f"cannot read the file: {e.strerror or e}") from None
    if not data:
        raise refuse(path, "the file is empty")
    # Pickle protocol 2+ starts with 0x80; torch.save writes a zip archive ("PK").
    if data[:1] == b"\x80" or data[:2] == b"PK":
        raise refuse(path, "the file is a pickle / torch archive, not ONNX; pickles are never loaded")
    return data


def session(path: Path, data: bytes, threads: int):  # noqa: ANN201 - onnxruntime.InferenceSession
    """A single-threaded-by-default CPU inference session of ``data``."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    opts.log_severity_level = 3
    try:
        return ort.InferenceSession(data, sess_options=opts, providers=["CPUExecutionProvider"])
    except Exception as e:  # onnxruntime raises its own Fail/InvalidGraph/... types
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise refuse(path, f"not a loadable ONNX model (corrupted or truncated?): {first}") from None


def metadata(path: Path, sess: object) -> PolicyMetadata:
    """The parsed ``custom_metadata_map`` (either dialect, ``deploy.metadata``)."""
    props = dict(sess.get_modelmeta().custom_metadata_map)  # type: ignore[attr-defined]
    if not props:
        raise refuse(
            path, "the file has no metadata; export it with bar_policy (every bar.* key is required)"
        )
    try:
        return PolicyMetadata.from_props(props)
    except MetadataError as e:
        raise refuse(path, str(e)) from e


def action_clip(path: Path, sess: object) -> float | None:
    """``bar.action_clip`` of the file (a number > 0, or None for no clip), else ``DEFAULT_ACTION_CLIP``."""
    props = sess.get_modelmeta().custom_metadata_map  # type: ignore[attr-defined]
    if ACTION_CLIP_KEY not in props:
        return DEFAULT_ACTION_CLIP
    try:
        value = loads_json(props[ACTION_CLIP_KEY], f"metadata key {ACTION_CLIP_KEY!r}", MetadataError)
    except MetadataError as e:
        raise refuse(path, str(e)) from None
    if value is None:
        return None
    number = isinstance(value, int | float) and not isinstance(value, bool)
    # An int past the float range (JSON allows any) is refused like inf, not an OverflowError.
    clip = float(value) if number and abs(value) <= sys.float_info.max else math.nan
    if not (math.isfinite(clip) and clip > 0):
        raise refuse(
            path, f"metadata key {ACTION_CLIP_KEY!r} must be a number > 0 or null, got {shorten(repr(value))}"
        )
    return clip


def _io_shape_ok(shape: list, size: int) -> bool:
    """``[batch, size]`` where batch is symbolic, unknown or 1."""
    if len(shape) != 2:
        return False
    batch, n = shape
    batch_ok = not isinstance(batch, int) or batch in (1, -1) or batch is None
    return batch_ok and n == size


def check_io(path: Path, sess: object, obs_size: int, n_actions: int) -> None:
    """Check the graph's I/O and run one test inference on a zero observation.

    One float32 input ``obs`` [batch, obs_size] and a float32 output ``actions`` [batch, n_actions]; the test
    inference must return float32 (1, n_actions).
    """
    inputs = sess.get_inputs()  # type: ignore[attr-defined]
    outputs = sess.get_outputs()  # type: ignore[attr-defined]
    if len(inputs) != 1 or inputs[0].name != "obs":
        raise refuse(
            path, f"the graph must have exactly one input named 'obs'; it has {[i.name for i in inputs]}"
        )
    out = [o for o in outputs if o.name == "actions"]
    if not out:
        raise refuse(path, f"the graph has no output named 'actions'; outputs: {[o.name for o in outputs]}")
    for label, node, size in (("input 'obs'", inputs[0], obs_size), ("output 'actions'", out[0], n_actions)):
        if node.type != "tensor(float)":
            raise refuse(path, f"{label} has type {node.type}; float32 (tensor(float)) is required")
        if not _io_shape_ok(list(node.shape), size):
            raise refuse(path, f"{label} has shape {list(node.shape)}; expected [batch, {size}]")
    try:
        result = sess.run(["actions"], {"obs": np.zeros((1, obs_size), np.float32)})[0]  # type: ignore[attr-defined]
    except Exception as e:  # onnxruntime's own exception types
        raise refuse(path, f"a test inference on a zero observation failed: {e}") from None
    if result.dtype != np.float32 or result.shape != (1, n_actions):
        raise refuse(
            path,
            f"a test inference returned {result.dtype} {result.shape}; expected float32 (1, {n_actions})",
        )
