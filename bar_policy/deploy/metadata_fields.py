"""Parsers of single metadata keys and the ``bar``/HC agreement check (``metadata.PolicyMetadata`` uses them).

Each refuses a malformed value with a ``MetadataError`` naming the key; ``provenance_key`` never refuses
(provenance informs only). numpy-free and jax-free, like ``metadata``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

from bar_policy._files import InputError, loads_json, shorten
from bar_policy.robot.gains import GAINS

__all__ = [
    "MetadataError",
    "action_filter_key",
    "check_agreement",
    "command_transition_key",
    "csv_float",
    "csv_floats",
    "csv_names",
    "gains_key",
    "int_prop",
    "provenance_key",
    "robot_params_key",
    "song_lead_key",
]

_HC_REL_TOL = 1e-5
"""Relative tolerance between a ``bar.*`` number and its HC copy (written with ``%.6g``)."""
_HC_ABS_TOL = 1e-6
"""Absolute tolerance for the same comparison (values near 0)."""


class MetadataError(InputError):
    """A policy file's metadata is missing, malformed or inconsistent (any malformed value raises this).

    Every ``bar.*`` value is parsed by ``_files.loads_json``: invalid JSON and nesting deeper than
    ``_files.MAX_JSON_DEPTH`` are refused, and values echoed in a message are cut to ``_files.ECHO_LIMIT``
    characters.
    """


def provenance_key(text: str | None) -> dict[str, Any]:
    """``bar.provenance`` as ``provenance.read_record`` reads it; a malformed one never refuses the file."""
    if text is None:
        return {}
    try:
        loads_json(text, "metadata key 'bar.provenance'", MetadataError)
    except MetadataError as e:  # informs only: the problem takes the record's place
        return {"error": str(e)}
    from bar_policy.provenance import read_record  # imported here: bar-deploy starts (and sees SIGINT) sooner

    return read_record(text)


def action_filter_key(props: Mapping[str, str]) -> float | None:
    """The optional ``bar.action_filter`` key: ``{"cutoff_hz": f}`` or null; absent in older files."""
    text = props.get("bar.action_filter")
    if text is None:
        return None
    v = loads_json(text, "metadata key 'bar.action_filter'", MetadataError)
    if v is None:
        return None
    if not isinstance(v, dict) or set(v) != {"cutoff_hz"} or isinstance(v["cutoff_hz"], bool):
        raise MetadataError(
            "metadata key 'bar.action_filter' must be null or {\"cutoff_hz\": <Hz>}, got "
            f"{shorten(repr(text))}"
        )
    return v["cutoff_hz"]


def robot_params_key(props: Mapping[str, str]) -> dict[str, Any]:
    """The optional ``bar.robot_params`` key: ``{"sha256": <64 hex>, "summary": {...}}``; ``{}`` if absent."""
    text = props.get("bar.robot_params")
    if text is None:
        return {}
    v = loads_json(text, "metadata key 'bar.robot_params'", MetadataError)
    sha = v.get("sha256") if isinstance(v, dict) else None
    if not (
        isinstance(sha, str) and len(sha) == 64 and all(c in "0123456789abcdef" for c in sha)
    ) or not isinstance(v.get("summary", {}), dict):
        raise MetadataError(
            'metadata key \'bar.robot_params\' must be {"sha256": <64 lower-case hex digits>, "summary": '
            f"{{...}}}}, got {shorten(repr(text))}"
        )
    return v


def csv_names(props: Mapping[str, str], key: str) -> tuple[str, ...]:
    """Comma-separated names (``""`` -> ``()``); empty items between commas are refused."""
    text = props[key].strip()
    if not text:
        return ()
    items = tuple(x.strip() for x in text.split(","))
    if any(not x for x in items):
        raise MetadataError(
            f"metadata key {key!r} has an empty name between commas: {shorten(repr(props[key]))}"
        )
    return items


def csv_floats(props: Mapping[str, str], key: str) -> tuple[float, ...]:
    """Comma-separated numbers; a non-number is refused naming it."""
    out = []
    for x in csv_names(props, key):
        try:
            out.append(float(x))
        except ValueError:
            raise MetadataError(
                f"metadata key {key!r} must be comma-separated numbers; {shorten(repr(x))} is not"
            ) from None
    return tuple(out)


def csv_float(props: Mapping[str, str], key: str) -> float:
    """Exactly one number (``policy_dt``)."""
    values = csv_floats(props, key)
    if len(values) != 1:
        raise MetadataError(f"metadata key {key!r} must be one number, got {shorten(repr(props[key]))}")
    return values[0]


def check_agreement(meta: Any, props: Mapping[str, str]) -> None:
    """Refuse a file whose ``bar.*`` keys and HC keys disagree (naming both keys and the first difference).

    ``meta`` is the ``metadata.PolicyMetadata`` read from the ``bar.*`` keys (not imported here: that
    module imports this one).
    """

    def refuse(key: str, detail: str) -> MetadataError:
        return MetadataError(
            f"metadata keys 'bar.{key}' and {key!r} (Humanoid Control) disagree: {shorten(detail, 500)}; "
            "Humanoid Control "
            "and bar-deploy would run this file differently, re-export it"
        )

    def names(key: str, ours: tuple[str, ...], theirs: tuple[str, ...]) -> None:
        if ours == theirs:
            return
        if len(ours) != len(theirs):
            raise refuse(key, f"{len(ours)} names {list(ours)} vs {len(theirs)} names {list(theirs)}")
        i = next(i for i, (a, b) in enumerate(zip(ours, theirs, strict=True)) if a != b)
        raise refuse(key, f"index {i} is {ours[i]!r} vs {theirs[i]!r}")

    def numbers(key: str, ours: tuple[float, ...], labels: tuple[str, ...]) -> None:
        theirs = csv_floats(props, key)
        if len(ours) != len(theirs):
            raise refuse(key, f"{len(ours)} values vs {len(theirs)}")
        bad = [
            f"{labels[i]}: {a:g} vs {b:g}"
            for i, (a, b) in enumerate(zip(ours, theirs, strict=True))
            if not math.isclose(a, b, rel_tol=_HC_REL_TOL, abs_tol=_HC_ABS_TOL)
        ]
        if bad:
            raise refuse(key, ", ".join(bad[:4]) + (f" (and {len(bad) - 4} more)" if len(bad) > 4 else ""))

    names("joint_names", meta.joint_names, csv_names(props, "joint_names"))
    names("action_joint_names", meta.action_joint_names, csv_names(props, "action_joint_names"))
    numbers("joint_stiffness", meta.joint_stiffness, meta.joint_names)
    numbers("joint_damping", meta.joint_damping, meta.joint_names)
    numbers("default_joint_pos", meta.default_joint_pos, meta.joint_names)
    numbers("action_scale", meta.action_scale, meta.action_joint_names)
    numbers("policy_dt", (meta.policy_dt,), ("policy_dt",))
    names("command_names", meta.command_names, csv_names(props, "command_names"))
    schema_terms = json.loads(meta.obs_schema).get("terms", [])
    terms = (
        tuple(t.get("name") for t in schema_terms if isinstance(t, dict))
        if isinstance(schema_terms, list)
        else ()
    )
    theirs = csv_names(props, "observation_names")
    if terms != theirs:
        raise MetadataError(
            f"metadata keys 'bar.obs_schema' (terms {shorten(list(terms))}) and 'observation_names' "
            f"(Humanoid Control: {shorten(list(theirs))}) disagree; Humanoid Control and bar-deploy would "
            "build different observations, re-export it"
        )


def int_prop(props: Mapping[str, str], key: str) -> int:
    """A non-negative integer HC key (``lookahead_steps``); refuses anything else naming the key."""
    text = props[key].strip()
    try:
        if not (text.isascii() and text.isdigit()):  # "¹" is a digit to isdigit, not to int
            raise ValueError(text)
        return int(text)
    except ValueError:  # also more digits than int() converts
        raise MetadataError(
            f"metadata key {key!r} must be a non-negative integer, got {shorten(repr(props[key]))}"
        ) from None


def command_transition_key(props: Mapping[str, str]) -> float:
    """Optional key ``bar.command_transition``: ``{"duration_s": s, "profile": "min_jerk"}``; absent: 0."""
    text = props.get("bar.command_transition")
    if text is None:
        return 0.0
    v = loads_json(text, "metadata key 'bar.command_transition'", MetadataError)
    if (
        not isinstance(v, dict)
        or set(v) != {"duration_s", "profile"}
        or v["profile"] != "min_jerk"
        or isinstance(v["duration_s"], bool)
        or not isinstance(v["duration_s"], int | float)
    ):
        raise MetadataError(
            'metadata key \'bar.command_transition\' must be {"duration_s": <s>, "profile": "min_jerk"} '
            f"(the only profile), got {shorten(repr(text))}"
        )
    return float(v["duration_s"])


def song_lead_key(props: Mapping[str, str]) -> int:
    """Optional key ``bar.song_lead_steps``: an integer >= 0; absent (older files, other tasks): 0.

    The control steps the piano's goal keys lead the song (``tasks.piano.bank.PlaybackConfig``).
    """
    text = props.get("bar.song_lead_steps")
    if text is None:
        return 0
    v = loads_json(text, "metadata key 'bar.song_lead_steps'", MetadataError)
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        raise MetadataError(
            "metadata key 'bar.song_lead_steps' must be an integer >= 0 (control steps), got "
            f"{shorten(repr(text))}"
        )
    return v


def gains_key(props: Mapping[str, str]) -> str:
    """Optional key ``bar.gains``: the gain profile the file trained on, one of ``robot.gains.GAINS``.

    Absent (files before the key, and every file on the joint table's gains): ``robot``.
    """
    text = props.get("bar.gains")
    if text is None:
        return "robot"
    v = loads_json(text, "metadata key 'bar.gains'", MetadataError)
    if v not in GAINS:
        raise MetadataError(
            f"metadata key 'bar.gains' must be one of {list(GAINS)}, got {shorten(repr(text))}"
        )
    return str(v)
