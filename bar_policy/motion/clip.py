"""Motion clips: joint positions of the Lite in canonical order at a stated rate (numpy only, no jax).

A clip is a name, a rate (Hz), the joint set (names, canonical order of a robot mode) and the frames,
shape ``(T, n)`` in rad. Body poses are not stored: they follow from the robot's own kinematics
(``bar_policy.robot.kinematics``), so training, evaluation and deployment use one set of numbers.

File format (NPZ, ``np.savez``, read with ``allow_pickle=False``), version ``bar_policy.motion/1``:

==============  =====================  ===========================================================
key             dtype / shape          meaning
==============  =====================  ===========================================================
format          str                    ``bar_policy.motion/1``
name            str                    clip name
rate_hz         float64 ()             frame rate, Hz
joint_names     str (n,)               canonical joint order of a robot mode (14 or 17 joints)
joint_pos       float32 (T, n)         joint positions, rad
content_hash    str                    ``content_hash`` of the above (the name excluded)
==============  =====================  ===========================================================

CSV import (``load_csv``): a header row of joint names (any order, exactly the mode's joint set), one row
per frame in rad, plus an optional ``time`` column in s (uniformly spaced; it sets the rate), otherwise
pass ``rate_hz``.

Every load validates the clip (``validate_clip``) and refuses, naming the frame (index and time) and the
joint, a clip that leaves the joint limits, moves a joint faster than ``MAX_JOINT_SPEED`` between two
frames, has non-finite values, or does not hold exactly the mode's joints in canonical order.

Loads are bounded before the frames are read, each refusal naming the limit and its value: a file of at
most ``MAX_CLIP_BYTES`` (an NPZ's members counted uncompressed), at most ``MAX_CLIP_FRAMES`` frames, and at
most ``MAX_CLIP_S`` long. A CSV is parsed ``CSV_CHUNK_ROWS`` rows at a time by numpy's C parser: a
10^6-row file took 83 s and 2 GB row by row, and a SIGINT (``KeyboardInterrupt``) now acts between two
chunks, within a few tens of ms.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import itertools
import math
import zipfile
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bar_policy._files import NPZ_LOAD_ERRORS, InputError, npz_problem, shorten
from bar_policy.robot.constants import MODES, RobotSpec, load_robot
from bar_policy.signals import check_stop

__all__ = [
    "CLIP_FORMAT",
    "CSV_CHUNK_ROWS",
    "LIMIT_TOLERANCE",
    "MAX_CLIP_BYTES",
    "MAX_CLIP_FRAMES",
    "MAX_CLIP_S",
    "MAX_JOINT_SPEED",
    "Clip",
    "ClipError",
    "check_clip_size",
    "content_hash",
    "load_clip",
    "load_csv",
    "save_clip",
    "validate_clip",
]

CLIP_FORMAT = "bar_policy.motion/1"
"""Format tag of the NPZ file."""

MAX_JOINT_SPEED = 5.0
"""Largest joint speed a clip may ask for, rad/s, every joint (finite difference of consecutive frames).

Why this number: it is above fast human arm gestures (a brisk wave peaks near 3 rad/s at the elbow), so
real recordings pass, and it is 0.1 rad per 50 Hz control step: a larger jump between two frames is a
glitch (a dropped teleoperation frame, an angle wrapping by 2*pi, degrees read as radians) that would ask
the MIT law for a torque step of Kp * 0.1 = 5 N*m from rest. The actuators' own limits are far higher
(33-76 rad/s, ``RobstrideSpec.velocity_limit``) and are not what limits a safe reference."""

MAX_CLIP_S = 600.0
"""Longest clip, s (time of its last frame; 10 min: the gestures last seconds, recordings minutes)."""

MAX_CLIP_FRAMES = 120_000
"""Most frames in a clip (10 min at 200 Hz; a clip is resampled to the 50 Hz control rate)."""

MAX_CLIP_BYTES = 64 * 1024 * 1024
"""Largest clip file, bytes (an NPZ's members uncompressed): 120 000 frames of 17 joints are 8 MB as
float32 and about 25 MB as CSV text."""

CSV_CHUNK_ROWS = 10_000
"""CSV rows parsed per call of numpy's parser (about 10 ms each): a SIGINT acts between two calls."""

LIMIT_TOLERANCE = 1e-6
"""Frames may pass a joint limit by this much, rad (float32 storage of a value on the limit)."""


class ClipError(InputError):
    """A clip that breaks the format, the joint set, the joint limits or the speed limit.

    ``load_clip`` and ``load_csv`` raise only this for a malformed file (empty, truncated, not an NPZ or
    CSV, wrong keys or types), naming the file; echoed values are cut to ``_files.ECHO_LIMIT`` characters.
    """


@dataclass(frozen=True, eq=False)
class Clip:
    """One motion clip. Construct with ``Clip.make`` (validates); frames are float32, shape (T, n)."""

    name: str
    """Clip name (not part of the hash)."""
    rate_hz: float
    """Frame rate, Hz."""
    joint_names: tuple[str, ...]
    """Canonical joint order of the frames."""
    joint_pos: np.ndarray
    """Joint positions, rad. Shape (T, n), float32, read-only."""

    @classmethod
    def make(
        cls,
        name: str,
        rate_hz: float,
        joint_pos: np.ndarray,
        mode: str = "arms",
        *,
        max_speed: float = MAX_JOINT_SPEED,
    ) -> Clip:
        """A validated clip of ``mode``'s joints from frames ``joint_pos`` (T, n), rad.

        Raises:
            ClipError: see ``validate_clip``.
        """
        robot = _robot(mode)
        q = np.array(joint_pos, dtype=np.float32)
        q.setflags(write=False)
        clip = cls(name=str(name), rate_hz=float(rate_hz), joint_names=robot.joint_names, joint_pos=q)
        validate_clip(clip, robot, max_speed=max_speed)
        return clip

    @property
    def num_frames(self) -> int:
        """T."""
        return int(self.joint_pos.shape[0])

    @property
    def duration_s(self) -> float:
        """Time of the last frame, s ((T - 1) / rate)."""
        return (self.num_frames - 1) / self.rate_hz

    @property
    def mode(self) -> str:
        """The robot mode whose joint set the clip holds."""
        return next(m for m in MODES if load_robot(m).joint_names == self.joint_names)

    @property
    def content_hash(self) -> str:
        """``content_hash`` of this clip (16 hex digits)."""
        return content_hash(self.rate_hz, self.joint_names, self.joint_pos)

    def resample(self, rate_hz: float) -> Clip:
        """The clip at another rate by linear interpolation (same duration, last frame kept).

        Linear interpolation keeps every frame inside the limits and never raises the speed.
        """
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ClipError(f"rate must be a positive number of Hz, got {rate_hz!r}")
        if rate_hz == self.rate_hz:
            return self
        t_old = np.arange(self.num_frames) / self.rate_hz
        n_new = math.floor(self.duration_s * rate_hz + 1e-9) + 1
        t_new = np.arange(n_new) / rate_hz
        q = np.stack([np.interp(t_new, t_old, col) for col in self.joint_pos.astype(np.float64).T], axis=1)
        return Clip.make(self.name, rate_hz, q, self.mode)


def content_hash(rate_hz: float, joint_names: tuple[str, ...], joint_pos: np.ndarray) -> str:
    """16 hex digits of sha256 over the rate, the joint names and the float32 little-endian frames."""
    h = hashlib.sha256()
    h.update(f"{CLIP_FORMAT}|{float(rate_hz)!r}|{','.join(joint_names)}|{joint_pos.shape}|".encode())
    h.update(np.ascontiguousarray(joint_pos, dtype="<f4").tobytes())
    return h.hexdigest()[:16]


def _robot(mode: str) -> RobotSpec:
    if mode not in MODES:
        raise ClipError(f"unknown mode {mode!r}; valid modes: {list(MODES)}")
    return load_robot(mode)


def check_file_size(path: Path, size: int) -> None:
    """Refuse more than ``MAX_CLIP_BYTES`` of clip data (``size``: the file's bytes, or an NPZ's unpacked)."""
    if size > MAX_CLIP_BYTES:
        raise ClipError(
            f"{path}: {size / 2**20:.4g} MiB of clip data; a clip file may hold at most "
            f"{MAX_CLIP_BYTES / 2**20:.4g} MiB (bar_policy.motion.clip.MAX_CLIP_BYTES): cut the clip or "
            "lower its rate"
        )


def check_clip_size(what: str, frames: int, rate_hz: float | None = None) -> None:
    """Refuse more than ``MAX_CLIP_FRAMES`` frames, or (with ``rate_hz``) a clip longer than ``MAX_CLIP_S``.

    ``ClipError`` naming the limit and its value. Loaders call it while they read, to stop early.
    """
    if frames > MAX_CLIP_FRAMES:
        raise ClipError(
            f"{what}: more than {MAX_CLIP_FRAMES} frames; a clip may have at most {MAX_CLIP_FRAMES} "
            "(bar_policy.motion.clip.MAX_CLIP_FRAMES): cut the clip or lower its rate"
        )
    if rate_hz is not None and rate_hz > 0 and (frames - 1) / rate_hz > MAX_CLIP_S:
        raise ClipError(
            f"{what}: {frames} frames at {rate_hz:.4g} Hz last {(frames - 1) / rate_hz:.4g} s; a clip may "
            f"last at most {MAX_CLIP_S:g} s (bar_policy.motion.clip.MAX_CLIP_S): cut it into shorter clips"
        )


def validate_clip(clip: Clip, robot: RobotSpec | None = None, *, max_speed: float = MAX_JOINT_SPEED) -> None:
    """Refuse a clip that the robot cannot or must not follow.

    Checks, in order: rate > 0; joint set and order equal to ``robot``'s (default: the mode holding the
    clip's joints, else arms); frames shaped (T >= 2, n), within ``check_clip_size``, and finite; every
    frame within the joint limits (+- ``LIMIT_TOLERANCE``); every joint's speed between consecutive frames
    <= ``max_speed`` rad/s.

    Raises:
        ClipError: the message names the clip, the frame (index and time) and the joint.
    """
    name = shorten(clip.name)
    if not (math.isfinite(clip.rate_hz) and clip.rate_hz > 0):
        raise ClipError(f"clip {name!r}: rate must be a positive number of Hz, got {clip.rate_hz!r}")
    if robot is None:
        modes = [m for m in MODES if load_robot(m).joint_names == tuple(clip.joint_names)]
        robot = load_robot(modes[0] if modes else "arms")
    want = robot.joint_names
    got = tuple(clip.joint_names)
    if got != want:
        missing = [j for j in want if j not in got]
        unknown = [j for j in got if j not in want]
        detail = f"missing {missing}, unknown {unknown}" if missing or unknown else "order differs"
        raise ClipError(
            f"clip {name!r}: joint set does not match mode {robot.mode!r} ({detail}); expected the "
            f"canonical order {list(want)}"
        )
    q = clip.joint_pos
    if q.ndim != 2 or q.shape[1] != len(want) or q.shape[0] < 2:
        raise ClipError(f"clip {name!r}: frames must have shape (T >= 2, {len(want)}), got {q.shape}")
    check_clip_size(f"clip {name!r}", q.shape[0], clip.rate_hz)

    def where(frame: int, joint: int) -> str:
        return f"clip {name!r}, frame {frame} (t = {frame / clip.rate_hz:.3f} s), joint {want[joint]!r}"

    bad = np.argwhere(~np.isfinite(q))
    if bad.size:
        f, j = bad[0]
        raise ClipError(f"{where(f, j)}: non-finite value {float(q[f, j])}")
    lo, hi = robot.lower - LIMIT_TOLERANCE, robot.upper + LIMIT_TOLERANCE
    bad = np.argwhere((q < lo) | (q > hi))
    if bad.size:
        f, j = bad[0]
        raise ClipError(
            f"{where(f, j)}: position {float(q[f, j]):.4f} rad outside the joint limits "
            f"[{robot.lower[j]:.4f}, {robot.upper[j]:.4f}] rad"
        )
    speed = np.abs(np.diff(q.astype(np.float64), axis=0)) * clip.rate_hz
    bad = np.argwhere(speed > max_speed)
    if bad.size:
        f, j = bad[0]
        raise ClipError(
            f"{where(f + 1, j)}: speed {speed[f, j]:.2f} rad/s from the previous frame exceeds the clip "
            f"speed limit {max_speed} rad/s (bar_policy.motion.clip.MAX_JOINT_SPEED: a larger jump is a "
            "glitch, a wrapped angle or degrees read as radians)"
        )


def save_clip(clip: Clip, path: str | Path) -> Path:
    """Write ``clip`` as an NPZ file (format above); returns the path."""
    path = Path(path)
    with path.open("wb") as f:
        np.savez(
            f,
            format=np.array(CLIP_FORMAT),
            name=np.array(clip.name),
            rate_hz=np.array(clip.rate_hz, dtype=np.float64),
            joint_names=np.array(clip.joint_names),
            joint_pos=np.asarray(clip.joint_pos, dtype=np.float32),
            content_hash=np.array(clip.content_hash),
        )
    return path


def load_clip(path: str | Path, mode: str = "arms", *, max_speed: float = MAX_JOINT_SPEED) -> Clip:
    """Read and validate an NPZ clip for ``mode``; the stored hash must match the content.

    Raises:
        ClipError: a missing or malformed key, a hash mismatch, or any ``validate_clip`` refusal.
    """
    robot = _robot(mode)
    if Path(path).is_file() and Path(path).stat().st_size == 0:
        raise ClipError(f"{path}: not a readable NPZ clip (the file is empty)")
    if Path(path).is_file():
        check_file_size(Path(path), Path(path).stat().st_size)
        # The members' unpacked sizes bound the memory; np.load names a file that is no zip archive below.
        unpacked = 0
        with contextlib.suppress(zipfile.BadZipFile, OSError, ValueError), zipfile.ZipFile(path) as z:
            unpacked = sum(i.file_size for i in z.infolist())
        check_file_size(Path(path), unpacked)
    try:
        with np.load(Path(path), allow_pickle=False) as f:
            data = {k: f[k] for k in f.files}
    except NPZ_LOAD_ERRORS as e:
        raise ClipError(f"{path}: not a readable NPZ clip ({npz_problem(path, e)})") from None
    keys = ("format", "name", "rate_hz", "joint_names", "joint_pos", "content_hash")
    missing = [k for k in keys if k not in data]
    if missing:
        raise ClipError(f"{path}: clip file lacks keys {missing}; a clip has {list(keys)}")
    if data["format"].shape != () or str(data["format"]) != CLIP_FORMAT:
        raise ClipError(
            f"{path}: format {shorten(repr(str(data['format'])))}, this code reads {CLIP_FORMAT!r}"
        )
    for key in ("rate_hz", "joint_pos"):
        if data[key].dtype.kind not in "fiu":  # complex, bool or text: not a clip's numbers
            raise ClipError(f"{path}: {key} must hold real numbers, got dtype {data[key].dtype}")
    try:
        q = np.array(data["joint_pos"], dtype=np.float32)
        q.setflags(write=False)
        clip = Clip(
            name=str(data["name"]),
            rate_hz=float(data["rate_hz"]),
            joint_names=tuple(str(n) for n in np.asarray(data["joint_names"]).reshape(-1)),
            joint_pos=q,
        )
    except (TypeError, ValueError, OverflowError) as e:  # wrong dtypes or shapes
        raise ClipError(f"{path}: malformed clip keys ({shorten(e)})") from None
    validate_clip(clip, robot, max_speed=max_speed)
    if clip.content_hash != str(data["content_hash"]):
        raise ClipError(
            f"{path}: content hash {clip.content_hash} differs from the stored "
            f"{shorten(str(data['content_hash']))}; the file was edited or corrupted"
        )
    return clip


def load_csv(
    path: str | Path,
    mode: str = "arms",
    *,
    rate_hz: float | None = None,
    name: str | None = None,
    max_speed: float = MAX_JOINT_SPEED,
) -> Clip:
    """Import a CSV clip (header of joint names, optional ``time`` column in s, values in rad).

    Args:
        path: the CSV file.
        mode: robot mode whose joints the columns must be (any column order).
        rate_hz: frame rate, Hz; required without a ``time`` column, refused with one.
        name: clip name (default: the file stem).
        max_speed: speed limit, rad/s.

    Raises:
        ClipError: unknown or missing joint columns, unparsable numbers, non-uniform time, or any
            ``validate_clip`` refusal (frame index and time, joint).
    """
    robot = _robot(mode)
    path = Path(path)
    try:
        check_file_size(path, path.stat().st_size)
        with path.open(newline="") as f:
            header = [h.strip() for h in next(csv.reader([f.readline()]), [])]
            if header:
                _check_columns(path, header, robot, mode)
                values = _csv_values(path, f, len(header))
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise ClipError(f"{path}: not a readable CSV clip ({shorten(e)})") from None
    if not header or len(values) < 2:
        raise ClipError(f"{path}: needs a header row and at least two frames")
    if "time" in header:
        if rate_hz is not None:
            raise ClipError(f"{path}: give either a 'time' column or rate_hz, not both")
        t = values[:, header.index("time")]
        dt = np.diff(t)
        if not (np.all(np.isfinite(t)) and np.all(dt > 0) and np.ptp(dt) <= 1e-3 * dt.mean()):
            raise ClipError(f"{path}: the 'time' column must increase uniformly (spacing varies by > 0.1 %)")
        rate_hz = 1.0 / float(dt.mean())
    elif rate_hz is None:
        raise ClipError(f"{path}: no 'time' column; pass rate_hz")
    check_clip_size(str(path), len(values), rate_hz)
    q = values[:, [header.index(j) for j in robot.joint_names]]
    return Clip.make(name or path.stem, rate_hz, q, mode, max_speed=max_speed)


def _check_columns(path: Path, header: list[str], robot: RobotSpec, mode: str) -> None:
    """The header must name exactly the mode's joints (any order) plus an optional ``time``."""
    cols = [h for h in header if h != "time"]
    missing = [j for j in robot.joint_names if j not in cols]
    unknown = [c for c in cols if c not in robot.joint_names]
    if missing or unknown or len(set(cols)) != len(cols):
        raise ClipError(
            f"{path}: columns must be exactly the joints of mode {mode!r} (plus an optional 'time'); "
            f"missing {missing}, unknown {shorten(unknown)}; joints: {list(robot.joint_names)}"
        )


def _csv_values(path: Path, f: Iterable[str], width: int) -> np.ndarray:
    """The CSV's frames after its header, float64 (T, width): ``CSV_CHUNK_ROWS`` rows per numpy call.

    Blank lines are no frames. More than ``MAX_CLIP_FRAMES`` rows stop the read (``check_clip_size``); a
    chunk numpy cannot parse is read again row by row to name the problem (ragged rows, not a number).
    """
    chunks: list[np.ndarray] = []
    n = 0
    while lines := list(itertools.islice(f, CSV_CHUNK_ROWS)):
        lines = [ln for ln in lines if ln.strip()]  # blank lines are no frames
        if not lines:
            continue
        try:
            chunk = np.loadtxt(lines, delimiter=",", dtype=np.float64, ndmin=2, comments=None)
        except ValueError:
            chunk = _csv_rows(path, lines, width)
        if chunk.size and chunk.shape[1] != width:
            raise ClipError(f"{path}: rows have [{chunk.shape[1]}] values, the header {width}")
        n += len(chunk)
        check_clip_size(str(path), n)
        check_stop(f"reading {path}")  # a stop request acts between two chunks
        chunks.append(chunk.reshape(-1, width))
    return np.concatenate(chunks) if chunks else np.zeros((0, width))


def _csv_rows(path: Path, lines: list[str], width: int) -> np.ndarray:
    """One chunk parsed row by row (the csv module, ``float``): the refusal that numpy's parser gave."""
    rows = [r for r in csv.reader(lines) if r]
    widths = sorted({len(r) for r in rows})
    if widths != [width]:
        raise ClipError(f"{path}: rows have {widths} values, the header {width}")
    try:
        return np.array([[float(x) for x in r] for r in rows], dtype=np.float64).reshape(-1, width)
    except ValueError as e:
        raise ClipError(f"{path}: not a number ({shorten(e)})") from None
