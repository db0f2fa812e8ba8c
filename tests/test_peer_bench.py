"""bench/peer_playground.py (our env against MuJoCo Playground's) and bench/peer_assets.py.

The arithmetic and the asset packing run everywhere; the end-to-end smoke run needs Playground
(``pip install --no-deps playground==0.2.0 lxml tqdm``; not a project dependency) and is skipped without it.
It loads Playground's Berkeley Humanoid from box stand-ins for all 13 meshes: every mesh of that model is
visual only, so the physics is the real one.
"""

from __future__ import annotations

import io
import json
import math
import struct
import tarfile
from pathlib import Path

import numpy as np
import pytest
from script_modules import load_bench

peer_assets = load_bench("peer_assets")


def test_box_stl_is_a_closed_box_with_outward_normals():
    data = peer_assets.box_stl((0.02, 0.0, 0.12), (0.09, 0.125, 0.125))
    # 80-byte header + uint32 count + 12 triangles x 50 bytes = 684.
    assert len(data) == 80 + 4 + 12 * 50
    (count,) = struct.unpack_from("<I", data, 80)
    assert count == 12
    center = np.array([0.02, 0.0, 0.12])
    for i in range(12):
        vals = struct.unpack_from("<12f", data, 84 + 50 * i)
        n, tri = np.array(vals[:3]), np.array(vals[3:]).reshape(3, 3)
        # The stored normal points away from the centre and agrees with the winding (right-hand rule).
        assert n @ (tri.mean(0) - center) > 0
        assert np.cross(tri[1] - tri[0], tri[2] - tri[0]) @ n > 0
        # The triangle lies on the face the normal names: half size from the centre along that axis.
        axis = int(np.argmax(np.abs(n)))
        assert np.allclose(np.abs(tri[:, axis] - center[axis]), [0.09, 0.125, 0.125][axis])


def _stand_in_archive(tmp_path: Path) -> Path:
    """A berkeley_humanoid archive of box stand-ins for every mesh (the test has no snapshot)."""
    out = tmp_path / "bh.tar.xz"
    with tarfile.open(out, "w:xz") as tf:
        for name in peer_assets.MESHES:
            blob = peer_assets.box_stl((0.0, 0.0, 0.0), (0.05, 0.05, 0.05))
            info = tarfile.TarInfo(f"berkeley_humanoid/assets/{name}.stl")
            info.size = len(blob)
            tf.addfile(info, io.BytesIO(blob))
    return out


def test_ratios_by_hand():
    peer = load_bench("peer_playground")
    result = {
        "ours": "LiteReach",
        "peers": ["P"],
        # ours: 1000 env steps/s x 10 substeps = 1e4 physics steps/s, x 14 joints = 1.4e5
        # peer:  500 env steps/s x 10 substeps = 5e3 physics steps/s, x 12 joints = 6.0e4
        "physics": [
            {
                "side": "ours",
                "env": "LiteReach",
                "env_sps": 1000.0,
                "physics_sps": 1e4,
                "physics_sps_x_joints": 1.4e5,
            },
            {"side": "peer", "env": "P", "env_sps": 500.0, "physics_sps": 5e3, "physics_sps_x_joints": 6.0e4},
        ],
        "train": [
            {"side": "ours", "env": "LiteReach", "steady_env_sps": 300.0, "end_to_end_env_sps": 100.0},
            {"side": "peer", "env": "P", "steady_env_sps": 200.0, "end_to_end_env_sps": 50.0},
        ],
    }
    (r,) = peer.ratios(result)
    assert r["env_sps"] == pytest.approx(2.0)
    assert r["physics_sps"] == pytest.approx(2.0)
    assert r["physics_sps_x_joints"] == pytest.approx(1.4e5 / 6.0e4)  # 2.33: the target (>= 1) is met
    assert r["target_met"] is True
    assert r["train_steady_env_sps"] == pytest.approx(1.5)
    assert r["train_end_to_end_env_sps"] == pytest.approx(2.0)


def test_menagerie_errors_name_what_is_missing(tmp_path):
    peer = load_bench("peer_playground")
    with pytest.raises(SystemExit, match="--menagerie"):
        peer.use_menagerie(None, ["berkeley_humanoid"])
    with pytest.raises(SystemExit, match="berkeley_humanoid"):
        peer.use_menagerie(str(tmp_path), ["berkeley_humanoid"])
    assert peer.use_menagerie(None, []) is None


@pytest.mark.slow
def test_smoke_ours_and_berkeley_humanoid_side_by_side(tmp_path):
    pytest.importorskip("mujoco_playground")
    peer = load_bench("peer_playground")
    out = tmp_path / "peer.json"
    result = peer.main(["--smoke", "--menagerie", str(_stand_in_archive(tmp_path)), "--out", str(out)])
    saved = json.loads(out.read_text())
    assert [r["env"] for r in saved["physics"]] == ["LiteReach", "BerkeleyHumanoidJoystickFlatTerrain"]
    ours, bh = result["physics"]
    # LiteReach: 14 arm joints, 10 substeps of 2 ms per 20 ms step; Berkeley Humanoid: 12 leg joints,
    # 10 x 2 ms.
    assert (ours["joints"], ours["substeps"], bh["joints"], bh["substeps"]) == (14, 10, 12, 10)
    for row in (ours, bh):
        assert row["physics_sps"] == pytest.approx(row["env_sps"] * row["substeps"])
        assert row["physics_sps_x_joints"] == pytest.approx(row["physics_sps"] * row["joints"])
        assert math.isfinite(row["physics_sps"]) and row["physics_sps"] > 0
    assert saved["ratios"][0]["physics_sps_x_joints"] == pytest.approx(
        ours["physics_sps_x_joints"] / bh["physics_sps_x_joints"]
    )
