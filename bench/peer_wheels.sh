#!/usr/bin/env bash
# What bench/peer_playground.py needs on the GPU machine besides ../shared/gpu/wheels.sh's .whl/:
#  - .whl_peer/: MuJoCo Playground 0.2.0 (PyPI `playground`, module `mujoco_playground`, 8 MB) without
#    its dependencies. Of those, brax, ml-collections, mujoco and mujoco-mjx are in .whl/; absl-py, etils,
#    flax, jax, lxml (imported by Playground's dm_control swimmer when the package loads), orbax-checkpoint
#    and tqdm (imported by its mjx_env) are in the GPU image (KINDS.md's list). Left out on purpose:
#    warp-lang (149 MB, cannot travel; the bench runs MJX's JAX implementation) and mediapy (rendering
#    only, never imported by what the bench loads). Here: pip install --no-deps playground==0.2.0 lxml tqdm
#  - .peer_assets/berkeley_humanoid.tar.xz: the Berkeley Humanoid meshes (bench/peer_assets.py), packed
#    from the fetch tool's snapshot of github:HybridRobotics/berkeley_humanoid_description, whose git dir
#    is the first argument (default: where fetch puts it). Fetch it first when it is not there.
# Both folders are ignored by git (.gitignore). Run from the project root, after ../shared/gpu/wheels.sh:
#   bash bench/peer_wheels.sh [GIT_DIR]
set -euo pipefail
root=$(git rev-parse --show-toplevel)
cd "$root"
mkdir -p .whl_peer
plat=""
for p in manylinux_2_17_x86_64 manylinux2014_x86_64 manylinux_2_24_x86_64 manylinux_2_27_x86_64 manylinux_2_28_x86_64 manylinux_2_31_x86_64 manylinux_2_34_x86_64 manylinux_2_35_x86_64; do
  plat="$plat --platform $p"
done
for pkg in playground==0.2.0; do
  # shellcheck disable=SC2086
  python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp $plat -d .whl_peer "$pkg" 2>&1 | grep -v WARNING || true
done
git_dir=${1:-/work/.mirror/HybridRobotics+berkeley_humanoid_description/repo}
if [ -d "$git_dir" ]; then
  python3 bench/peer_assets.py --git-dir "$git_dir" --out .peer_assets/berkeley_humanoid.tar.xz | tail -1
else
  echo "no snapshot at $git_dir: fetch github:HybridRobotics/berkeley_humanoid_description, then run again" >&2
fi
du -sh .whl .whl_peer .peer_assets 2>/dev/null || true
du -sch .whl .whl_peer .peer_assets 2>/dev/null | tail -1
echo 'In the device run: carry [".whl", ".whl_peer", ".peer_assets"] and start the command with:'
echo 'python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl .whl_peer/*.whl >/dev/null && export PYTHONPATH=/tmp/site:$PWD || exit;'
