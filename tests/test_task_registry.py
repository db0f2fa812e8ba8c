"""The task registry: one record per task folder, read by the env registry, the layouts, the presets and
``bar-deploy``; a task's shared and deploy parts import with jax and torch blocked."""

from __future__ import annotations

import dataclasses
import importlib
import json
import re
import subprocess
import sys
from pathlib import Path

import onnx
import pytest
from blocked_imports import BLOCK_HEAVY

from bar_policy.deploy.tasks import HC_TASKS, TASK_COMMAND_TERMS, get_task, implied_task
from bar_policy.obs import SHIPPED_LAYOUTS, TERM_CATALOG, ObservationManager
from bar_policy.obs.robot_layout import with_error_ema
from bar_policy.task_records import EnvEntry, TaskRecord, resolve
from bar_policy.tasks.registry import TASK_PACKAGES, TASKS, get_task_record
from bar_policy.training.config import PRESETS, TrainConfig, preset

CHECKPOINTS = Path(__file__).resolve().parents[1] / "checkpoints"
TASKS_DIR = Path(__file__).resolve().parents[1] / "bar_policy" / "tasks"


def test_registry_lists_each_task_folder_once():
    """Every folder under ``bar_policy/tasks/`` with an ``__init__.py`` is a task, registered once (its line
    in ``TASK_PACKAGES``); reach comes first (the default env's task). The list is read from the folders, so
    adding or removing a task edits no test here."""
    folders = sorted(p.name for p in TASKS_DIR.iterdir() if (p / "__init__.py").is_file())
    assert sorted(r.name for r in TASKS) == folders
    assert TASKS[0].name == "reach"
    for package, record in zip(TASK_PACKAGES, TASKS, strict=True):
        assert package == f"bar_policy.tasks.{record.name}"
        assert get_task_record(record.name) is record
    valid = re.escape(str(sorted(r.name for r in TASKS)))
    with pytest.raises(ValueError, match=rf"unknown task 'dance'; valid tasks: {valid}"):
        get_task_record("dance")


def test_records_are_validated():
    entry = EnvEntry(name="LiteX", env="m.env:LiteX", config="m.env:default_config")
    with pytest.raises(ValueError, match=r"must be a 'package\.module:attribute' string, got 'm\.env'"):
        EnvEntry(name="LiteX", env="m.env", config="m.env:default_config")
    with pytest.raises(ValueError, match="registers no env"):
        TaskRecord(name="x", summary="", envs=(), layout="m.layout:schema")
    with pytest.raises(ValueError, match="lower_snake_case"):
        TaskRecord(name="X", summary="", envs=(entry,), layout="m.layout:schema")


@pytest.mark.parametrize("record", TASKS, ids=lambda r: r.name)
def test_every_env_loads_through_the_env_registry(record):
    from bar_policy import envs

    for entry in record.envs:
        assert entry.name in envs.ALL_ENVS
        env = envs.load(entry.name)
        assert type(env) is resolve(entry.env) and env.task_name == record.name
        assert type(env.config) is type(resolve(entry.config)())
        assert set(env.task_metadata()) == set(record.metadata_keys)
        assert (
            env.obs_manager.fingerprint
            == ObservationManager.for_task(record.name, env.config.mode).fingerprint
        )


@pytest.mark.parametrize("record", TASKS, ids=lambda r: r.name)
def test_presets_exist_and_train_a_registered_env(record):
    from bar_policy.tasks.registry import env_entries

    assert record.presets
    for name, ref in record.presets:
        cfg = preset(name)
        assert name in PRESETS and cfg.preset == name and cfg.env_name in env_entries()
        assert all(isinstance(k, str) for k in resolve(ref))  # plain data: {dotted.path: value}


def test_a_preset_is_its_overrides_on_the_base():
    """``track``: 8192 envs x 20-step unrolls on LiteTrack (``tasks/track/preset.py``), the rest the base."""
    base, track = TrainConfig(), preset("track")
    assert (track.env_name, track.ppo.num_envs, track.ppo.unroll_length) == ("LiteTrack", 8192, 20)
    assert track.network.action_prior == "reference" and track.network.policy_hidden == (256, 256, 128)
    assert track.ppo.clipping_epsilon == base.ppo.clipping_epsilon and track.seed == base.seed
    # gpu: the base but for its batch, update precision, evaluation cadence and 4 ms physics step
    # (tasks/reach/preset.py).
    gpu = preset("gpu")
    assert (gpu.ppo.batch_size, gpu.eval.num_evals, gpu.env_overrides) == (256, 24, ("sim_dt=0.004",))
    assert (gpu.ppo.update_precision, base.ppo.update_precision) == ("tensorfloat32", "run")
    ppo = dataclasses.replace(gpu.ppo, batch_size=base.ppo.batch_size, update_precision="run")
    rest = dataclasses.replace(gpu, eval=base.eval, ppo=ppo, env_overrides=())
    assert rest == TrainConfig(preset="gpu")


@pytest.mark.parametrize("record", TASKS, ids=lambda r: r.name)
def test_layouts_and_command_terms_come_from_the_record(record):
    for name, mode in record.shipped_layouts:
        assert SHIPPED_LAYOUTS[name] == (record.name, mode)
        om = ObservationManager.for_task(record.name, mode)
        assert om.fingerprint == ObservationManager.golden(name).fingerprint
        assert om.command_names == record.command_terms
    added = resolve(record.terms)
    assert all(TERM_CATALOG[name] is kind for name, kind in added.items())  # the catalogue reads the record
    assert set(record.command_terms) <= {n for n, k in added.items() if k.category == "command"}
    if not record.deploy:  # a task without a deploy side: bar-deploy lists it nowhere
        assert record.name not in TASK_COMMAND_TERMS and record.name not in HC_TASKS
        return
    assert TASK_COMMAND_TERMS[record.name] == record.command_terms
    assert get_task(record.name).name == record.name
    assert (record.name in HC_TASKS) == record.hc_only
    assert implied_task(record.implied_by[:1]) == record.name


def test_shipped_files_keep_their_layouts():
    """Every ONNX file in checkpoints/ carries a golden layout, or its opt-in next version with the
    ``joint_error_ema`` term (``obs.robot_layout.with_error_ema``: the robust reach file), and the code
    builds the same layout."""
    files = sorted(CHECKPOINTS.glob("*.onnx"))
    assert files
    for path in files:
        props = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
        schema = json.loads(props["bar.obs_schema"])
        task, mode = SHIPPED_LAYOUTS[schema["name"]]
        assert json.loads(props["bar.task"]) == task
        expected = ObservationManager.for_task(task, mode)
        if "joint_error_ema" in [t["name"] for t in schema["terms"]]:
            expected = ObservationManager(with_error_ema(expected.schema))
        assert json.loads(props["bar.obs_fingerprint"]) == expected.fingerprint


def test_shared_and_deploy_parts_import_with_jax_and_torch_blocked():
    script = BLOCK_HEAVY + (
        "import importlib\n"
        "from bar_policy.tasks.registry import TASKS\n"
        "for r in TASKS:\n"
        "    if r.deploy:\n"
        "        importlib.import_module(r.deploy)\n"
        "    importlib.import_module(r.layout.partition(':')[0])\n"
        "    for _, ref in r.presets:\n"
        "        importlib.import_module(ref.partition(':')[0])\n"
        "import bar_policy.deploy.tasks as t\n"
        "print([task.name for task in t.all_tasks()])\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, check=False
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.split("\n")[-2] == str([r.name for r in TASKS if r.deploy] + ["state"])


def test_the_blocker_blocks():
    out = subprocess.run(
        [sys.executable, "-c", BLOCK_HEAVY + "import bar_policy.tasks.reach.env\n"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert out.returncode != 0 and "jax is blocked in this test" in out.stderr


def test_every_env_module_is_a_task_module():
    """The env modules the records name live in their task's folder (a task imports no other task)."""
    for record in TASKS:
        for entry in record.envs:
            for ref in (entry.env, entry.config):
                assert ref.startswith(f"bar_policy.tasks.{record.name}."), ref
        assert not record.deploy or record.deploy.startswith(f"bar_policy.tasks.{record.name}.")
        folder = TASKS_DIR / record.name
        others = [f"bar_policy.tasks.{r.name}" for r in TASKS if r is not record]
        for path in folder.glob("*.py"):
            text = path.read_text()
            assert not any(o + "." in text or o + " " in text for o in others), path


def test_env_names_of_the_moved_modules_stay_on_envs():
    """The old ``bar_policy.envs.reach`` / ``.track`` / ``.track_config`` paths are gone (an env module
    importing a task would point up); their public names are still ``bar_policy.envs.<name>``."""
    import bar_policy.envs as envs

    for old, new in {
        "reach": "bar_policy.tasks.reach.env",
        "track": "bar_policy.tasks.track.env",
        "track_config": "bar_policy.tasks.track.config",
    }.items():
        assert not (Path(envs.__file__).parent / f"{old}.py").exists(), old
        module = importlib.import_module(new)
        for name in ("LiteReach", "ReachEnvConfig", "LiteTrack", "TrackEnvConfig"):
            if name in module.__all__:
                assert getattr(envs, name) is getattr(module, name), name
