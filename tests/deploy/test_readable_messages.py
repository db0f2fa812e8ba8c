"""Messages a user can act on: each reproduces a message that said nothing useful and checks the rewrite.

Numbers are printed with 4 significant digits (``:.4g``), no numpy repr (``np.float64(nan)``), no
300-digit numbers, and each names what to change.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from policy_factory import make_policy_file

from bar_policy.deploy.cli import main
from bar_policy.deploy.contract import PolicyLoadError
from bar_policy.deploy.log.read import load_log
from bar_policy.deploy.policy import load_policy
from bar_policy.deploy.safety_checks import check_action_scale
from bar_policy.motion.clip import Clip, ClipError, load_clip
from bar_policy.robot.constants import load_robot
from bar_policy.robstride.errors import CommandError
from bar_policy.robstride.protocol import encode_mit_batch
from bar_policy.tasks.reach.command_file import FileCommands

LONG_NUMBER = re.compile(r"\d{8,}")
"""Eight digits in a row: a number printed without a precision."""


def _status(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as e:
        return e.code if isinstance(e.code, int) else 1


def test_huge_action_clip_is_blamed_not_the_scale(tmp_path, capsys):
    # bar.action_clip 1e308 with the default action_scale 0.25: left_shoulder_pitch (default 0.3 rad,
    # range [-pi, 0.7854]) reaches 0.3 -+ 0.25e308 = [-2.5e+307, +2.5e+307] rad. Over +-1 it reaches
    # [0.05, 0.55]: inside, so the clip is what is wrong.
    path = make_policy_file(tmp_path / "clip.onnx", props={"bar.action_clip": "1e308"})
    with pytest.raises(PolicyLoadError) as err:
        load_policy(path)
    msg = str(err.value)
    assert "metadata key 'bar.action_clip' = 1e+308 lets the actions reach beyond the joint ranges" in msg
    assert "(14 of 14 joints; the action_scale is fine over +-1)" in msg
    assert "reaches [-2.5e+307, +2.5e+307] rad, beyond its range [-3.142, +0.7854] rad" in msg
    assert "Export the clip the policy was trained with" in msg
    assert not LONG_NUMBER.search(msg), msg
    assert _status(["--policy", str(path), "--target", "mock", "--log", str(tmp_path / "runs")]) == 2
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "bar.action_clip" in lines[0] and not LONG_NUMBER.search(lines[0])


def test_a_scale_too_large_is_still_blamed_on_the_scale(tmp_path):
    """With the clip at its default (1), a large scale is the scale's fault, as before."""
    from policy_factory import default_metadata

    scale = [0.25] * 14
    scale[3] = 3.0  # left_elbow_pitch: default -1.7 -+ 3 = [-4.7, +1.3] vs [-2.356, 0]
    with pytest.raises(PolicyLoadError, match=r"action_scale beyond the joint ranges: left_elbow_pitch"):
        load_policy(
            make_policy_file(tmp_path / "s.onnx", metadata=default_metadata(action_scale=tuple(scale)))
        )


def test_joint_set_mismatch_says_what_to_change(tmp_path):
    # A file that says arms_neck but lists the 14 arm joints: the old message read "'arms_neck' (14 joints)
    # ... 'arms' (14 joints)". arms_neck has 17 joints: the arms' 14 and the neck's 3.
    path = make_policy_file(tmp_path / "neck.onnx", props={"bar.mode": '"arms_neck"'})
    with pytest.raises(PolicyLoadError) as err:
        load_policy(path, mode="arms")
    msg = str(err.value)
    neck = [n for n in load_robot("arms_neck").joint_names if n not in load_robot("arms").joint_names]
    assert neck == ["neck_yaw", "neck_roll", "neck_pitch"]
    assert (
        "joint set mismatch: the policy drives mode 'arms_neck' (17 joints), this run drives mode 'arms' "
        f"(14 joints; it adds {neck}); give --mode arms_neck to run it on that joint set, or a policy "
        "trained for 'arms'; its joint_names list 14 joints, not 17: the file is inconsistent, re-export it"
    ) in msg
    arms = make_policy_file(tmp_path / "arms.onnx")
    with pytest.raises(
        PolicyLoadError, match=r"\(17 joints; it lacks \['neck_yaw', 'neck_roll', 'neck_pitch'\]\)"
    ):
        load_policy(arms, mode="arms_neck")


def test_no_numpy_reprs_in_messages():
    lo, up = np.array([-1.0]), np.array([1.0])
    (msg,) = check_action_scale([0.0], np.array([np.nan]), lo, up, ["j"])
    assert msg == "j: action_scale nan is not a finite number >= 0 rad per action unit"
    robot = load_robot("arms")
    q = np.tile((robot.lower + robot.upper) / 2, (3, 1)).astype(np.float32)
    q[1, 2] = np.nan
    with pytest.raises(ClipError) as err:
        Clip.make("c", 50.0, q)
    assert str(err.value).endswith("joint 'left_shoulder_yaw': non-finite value nan")
    from bar_policy.robot.mit import wire_ranges

    values = np.zeros((5, 1))
    values[4, 0] = np.inf  # tau_ff
    with pytest.raises(CommandError) as err:
        encode_mit_batch([11], wire_ranges(["rs-03"]), values)
    assert "=inf for CAN id 11; nothing was sent" in str(err.value)
    for e in (msg, str(err.value)):
        assert "np.float" not in e


@pytest.fixture
def random_npz(tmp_path) -> Path:
    path = tmp_path / "random.npz"
    path.write_bytes(bytes([0x85, 0x62, 0x19, 0xC4]) + bytes(range(256)))  # not a zip, not .npy
    return path


def test_random_bytes_npz_is_not_called_pickled_data(random_npz):
    want = "not an NPZ archive: it does not start with a zip header (50 4b), but with 85 62 19 c4"
    with pytest.raises(ClipError) as clip_err:
        load_clip(random_npz)
    with pytest.raises(ValueError) as log_err:
        load_log(random_npz)
    with pytest.raises(ValueError) as cmd_err:
        FileCommands(("target_pos_left", "target_pos_right"), random_npz)
    for err in (clip_err, log_err, cmd_err):
        msg = str(err.value)
        assert want in msg and "pickle" not in msg and "allow_pickle" not in msg, msg
    npy = random_npz.with_name("one.npz")
    np.save(npy.with_suffix(".npy"), np.zeros(3))
    npy.with_suffix(".npy").rename(npy)
    with pytest.raises(ClipError, match=r"a single \.npy array, not an NPZ archive of named arrays"):
        load_clip(npy)


def test_a_refused_clip_file_is_named_once(tmp_path, capsys):
    """``--motion big.csv``: the loader's message starts with the path; the option does not repeat it."""
    from policy_factory import default_metadata

    from bar_policy.motion.clip import MAX_CLIP_BYTES

    policy = make_policy_file(tmp_path / "track.onnx", metadata=default_metadata(task="track"))
    big = tmp_path / "big.csv"
    with big.open("wb") as f:
        f.truncate(2 * MAX_CLIP_BYTES)  # sparse: 128 MiB without writing them
    argv = [
        "--policy",
        str(policy),
        "--motion",
        str(big),
        "--motion-rate",
        "50",
        "--log",
        str(tmp_path / "r"),
    ]
    assert _status(argv) == 2
    (line,) = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert line.count(str(big)) == 1, line
    assert f"--motion {big}: 128 MiB of clip data; a clip file may hold at most 64 MiB" in line
