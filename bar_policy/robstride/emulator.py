"""Robstride actuators on a python-can bus, driven by MuJoCo physics of the Lite (bus-level emulator).

Every emulated motor listens on its interface's bus (python-can ``virtual``; SocketCAN ``vcan`` where the
kernel has it), decodes the host's frames with the protocol layer, and answers like the firmware
(``firmware.py``: the per-motor state and its answer to one request); this module holds the buses, threads,
physics (``emulator_physics``) and clock:

- Physics (``emulator_physics.EmulatorPhysics``, inherited): each MuJoCo step (2 ms) the MIT law of every
  enabled motor, ``firmware_torque`` (the one shared actuator model) with the motor's ``limit_torque`` as
  the cap, goes into ``qfrc_applied``; over each step the law acts at the step's mean state, as a fast
  firmware applies it (``damping``). Disabled motors apply nothing. Joint <-> motor frames use the
  robot data's directions and the emulated robot's *true* homing offsets (``offsets``), so a calibration
  error shows up as it would on hardware.
- Time: ``mode="lockstep"`` advances ``control_dt`` of physics once every enabled motor has received a type-1
  frame (a complete command round) and only then answers that round's type-1 frames, with the post-step
  state (deterministic, faster than real time, the semantics of the synchronous sim target).
  ``mode="realtime"`` steps physics in a thread at the wall-clock rate and answers every frame at once.

Watchdog (``canTimeout``, 0x7028): per motor, the arrival time of the last frame addressed to it; an enabled
motor that hears nothing for ``ticks * watchdog_tick`` s (50 us ticks: 4000 = 0.2 s) goes to reset mode as
after a stop frame (``firmware.trip_watchdog``; trips in ``watchdog_trips``). The clock is the bus's
frame-timestamp clock (``time.time``, what python-can stamps ``virtual`` and SocketCAN frames with), so a
frame that arrived in time is never counted late when the emulator thread runs late. A disabled motor is
not affected.

Fault injection (``inject``, ``silence``, ``garbage_per_round``): dropped replies (all, or only the replies
to one request type: ``drop_only``), a reported temperature per motor (``temperature``), fault bits and
type-21 fault frames, replies from a wrong id, garbage frames, bus silence, active-report (0x18) chatter;
at construction: absent motors, wrong models, unknown extra devices.
"""

from __future__ import annotations

import logging
import random
import threading
import time
from collections.abc import Callable, Collection, Mapping, Sequence

import can
import mujoco
import numpy as np

from bar_policy.robot.constants import RobotSpec
from bar_policy.robot.index import RobotIndex
from bar_policy.robot.scene import SceneEdit, load_model
from bar_policy.robstride import firmware as fw
from bar_policy.robstride import framing, motor_side
from bar_policy.robstride.emulator_physics import EMULATOR_DAMPING, EmulatorPhysics
from bar_policy.robstride.errors import FrameError
from bar_policy.robstride.firmware import DEFAULT_LIMIT_CURRENT, EmulatedMotor, Injection, JointReading

__all__ = ["DEFAULT_LIMIT_CURRENT", "EMULATOR_MODES", "Injection", "RobstrideEmulator"]

log = logging.getLogger(__name__)

EMULATOR_MODES = ("lockstep", "realtime")
"""Physics clock modes."""


class RobstrideEmulator(EmulatorPhysics):
    """Emulated Robstride motors of a robot on python-can buses, backed by MuJoCo.

    Args:
        robot: the robot data; one motor per joint on the joint's ``can_interface``.
        channels: robot interface name (``can0``) -> python-can channel (``can0``, ``vcan0``, a test name).
        interface: python-can interface for the emulator's buses (``virtual``, or ``socketcan`` on vcan).
        mode: ``lockstep`` or ``realtime`` (module docstring).
        control_dt: physics advanced per complete command round in lockstep, s.
        offsets: true homing offset per joint name, rad (raw = direction * joint + offset); default 0.
        initial_q: initial joint positions, canonical order, rad; default the ``arms_hanging`` pose.
        models: joint name -> model actually installed (injects a wrong model); default the robot data's.
        absent: joint names whose motors are not on the bus.
        extra_ids: interface -> CAN ids of unknown devices (rs-00) that answer scans and frames.
        temperature: reported temperature of every motor, degC (``inject(key, temperature=...)`` sets one).
        seed: seed of the garbage-frame generator.
        watchdog_tick: seconds per canTimeout tick (the reference's 50 us; 1e-6 emulates the conflicting
            microsecond reading).
        clock: the emulator's clock, s; must be the clock of the buses' frame timestamps.
        scene: a task's additions to the robot's MuJoCo scene (``bar_policy.robot.scene``); None: the robot
            alone. The motors act on the robot's joints by name (``RobotIndex``).
        damping: how physics integrates the law's ``Kd`` term: ``trapezoid`` (the default: nearest the
            firmware's fast loop), ``implicit`` (the sim target's) or ``explicit`` (a 500 Hz law);
            ``emulator_physics``'s docstring.
    """

    def __init__(
        self,
        robot: RobotSpec,
        channels: Mapping[str, str],
        *,
        interface: str = "virtual",
        mode: str = "lockstep",
        control_dt: float = 0.02,
        offsets: Mapping[str, float] | None = None,
        initial_q: Sequence[float] | None = None,
        models: Mapping[str, str] | None = None,
        absent: Collection[str] = (),
        extra_ids: Mapping[str, Sequence[int]] | None = None,
        temperature: float = 30.0,
        seed: int = 0,
        watchdog_tick: float = framing.CAN_TIMEOUT_TICK,
        clock: Callable[[], float] = time.time,
        scene: SceneEdit | None = None,
        damping: str = EMULATOR_DAMPING[0],
    ) -> None:
        if mode not in EMULATOR_MODES:
            raise ValueError(f"unknown emulator mode {mode!r}; valid: {list(EMULATOR_MODES)}")
        if damping not in EMULATOR_DAMPING:
            raise ValueError(f"unknown emulator damping {damping!r}; valid: {list(EMULATOR_DAMPING)}")
        self.damping = damping
        used = {j.can_interface for j in robot.joints}
        unmapped = sorted(used - set(channels))
        if unmapped:
            raise ValueError(f"no channel given for robot interfaces {unmapped}; channels: {dict(channels)}")
        self.robot = robot
        self.mode = mode
        self.model = load_model(robot.mode, scene)
        self.data = mujoco.MjData(self.model)
        self.n_substeps = max(1, round(control_dt / self.model.opt.timestep))
        self.frozen = False
        """Lockstep: complete rounds are answered without advancing physics (an evaluation's start-up, whose
        activation takes no time on the episode's clock: ``EmulatedBusTarget.reset``)."""
        self.temperature = temperature
        if not watchdog_tick > 0:
            raise ValueError(f"watchdog_tick must be > 0 s, got {watchdog_tick!r}")
        self.watchdog_tick = watchdog_tick
        """Seconds per canTimeout tick."""
        self.clock = clock
        """The emulator's clock (frame timestamps, watchdog), s."""
        self.garbage_per_round = 0
        """Garbage frames sent after each answered round (lockstep) or frame (realtime)."""
        self._rng = random.Random(seed)
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._silent: set[str] = set()
        self._pending: list[tuple[EmulatedMotor, bytes]] = []
        self._commanded: set[tuple[str, int]] = set()
        self._static_cache = None  # EmulatorPhysics._static

        offsets = dict(offsets or {})
        models = dict(models or {})
        unknown = sorted((set(offsets) | set(models) | set(absent)) - set(robot.joint_names))
        if unknown:
            raise ValueError(f"unknown joints {unknown}; joints: {list(robot.joint_names)}")
        self.motors: dict[tuple[str, int], EmulatedMotor] = {}
        self._by_interface: dict[str, list[EmulatedMotor]] = {}
        for j in robot.joints:
            if j.name in absent:
                continue
            self._add(
                EmulatedMotor(
                    can_id=j.can_id,
                    model=models.get(j.name, j.model),
                    interface=j.can_interface,
                    name=j.name,
                    joint=j.index,
                    direction=j.direction,
                    offset=float(offsets.get(j.name, 0.0)),
                )
            )
        for iface, ids in (extra_ids or {}).items():
            for can_id in ids:
                extra = EmulatedMotor(
                    can_id=can_id, model="rs-00", interface=iface, name=f"extra{can_id}", joint=None
                )
                self._add(extra)

        self.index = RobotIndex.from_model(self.model, robot.joint_names)
        """Addresses of the robot's joints in the scene."""
        self._qadr, self._dadr = self.index.qpos, self.index.dof
        self._mjcf_damping = self.model.dof_damping[self._dadr].copy()
        q0 = robot.pose("arms_hanging") if initial_q is None else np.asarray(initial_q, dtype=np.float64)
        self.data.qpos[self._qadr] = q0
        mujoco.mj_forward(self.model, self.data)
        self._tau_raw = np.zeros(robot.num_joints)

        self.buses: dict[str, can.BusABC] = {
            iface: can.Bus(interface=interface, channel=channels[iface], receive_own_messages=False)
            for iface in sorted({m.interface for m in self.motors.values()} | used)
        }

    def _add(self, m: EmulatedMotor) -> None:
        m.params = fw.power_on_params(m.model)
        m.last_rx = self.clock()
        m.uid = fw.device_uid(m.interface, m.can_id)
        self.motors[(m.interface, m.can_id)] = m
        self._by_interface.setdefault(m.interface, []).append(m)

    # ----------------------------------------------------------------------------------------------
    # lifecycle
    def start(self) -> RobstrideEmulator:
        """Start the receiver threads (and the physics thread in realtime mode)."""
        if self._threads:
            return self
        for iface, bus in self.buses.items():
            t = threading.Thread(target=self._serve, args=(iface, bus), name=f"emu-{iface}", daemon=True)
            self._threads.append(t)
        if self.mode == "realtime":
            self._threads.append(threading.Thread(target=self._physics_loop, name="emu-physics", daemon=True))
        for t in self._threads:
            t.start()
        return self

    def close(self) -> None:
        """Stop the threads and shut the buses down. Safe to call twice."""
        self._stop.set()
        for t in self._threads:
            t.join(timeout=2.0)
        self._threads.clear()
        for bus in self.buses.values():
            bus.shutdown()

    def __enter__(self) -> RobstrideEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ----------------------------------------------------------------------------------------------
    # fault injection and inspection
    def motor(self, key: str | int) -> EmulatedMotor:
        """The emulated motor of a joint name or CAN id."""
        for m in self.motors.values():
            if key in (m.name, m.can_id):
                return m
        raise KeyError(f"no emulated motor {key!r}; motors: {sorted(m.name for m in self.motors.values())}")

    def inject(self, key: str | int, **changes: object) -> None:
        """Change a motor's ``Injection`` fields (e.g. ``inject("left_elbow_pitch", drop_replies=1)``)."""
        m = self.motor(key)
        with self._lock:
            for k, v in changes.items():
                if not hasattr(m.inj, k):
                    raise ValueError(
                        f"unknown injection {k!r}; valid: {list(Injection.__dataclass_fields__)}"
                    )
                setattr(m.inj, k, v)

    def silence(self, interface: str, on: bool = True) -> None:
        """Bus silence: the motors on ``interface`` neither hear nor answer anything."""
        with self._lock:
            (self._silent.add if on else self._silent.discard)(interface)

    @property
    def sim_time(self) -> float:
        """Physics time, s."""
        return float(self.data.time)

    def joint_positions(self) -> np.ndarray:
        """True joint positions, canonical order, rad."""
        with self._lock:
            return self.data.qpos[self._qadr].copy()

    def set_joint_positions(self, q: Sequence[float], *, scene_at_rest: bool = False) -> None:
        """Teleport the joints (e.g. to play a hand sweep for calibration), zero velocity.

        ``scene_at_rest``: also put the scene's other joints (a task's, e.g. the piano's keys) back at
        ``qpos0``, as a fresh episode starts them.
        """
        with self._lock:
            if scene_at_rest:
                self.data.qpos[:] = self.model.qpos0
            self.data.qpos[self._qadr] = np.asarray(q, dtype=np.float64)
            self.data.qvel[:] = 0.0
            mujoco.mj_forward(self.model, self.data)

    def enabled(self) -> dict[str, bool]:
        """Joint name -> enabled."""
        with self._lock:
            return {m.name: m.enabled for m in self.motors.values()}

    # ----------------------------------------------------------------------------------------------
    # the firmware side of the protocol
    def _joint(self, m: EmulatedMotor) -> JointReading | None:
        """What ``m`` sees of its joint now (lock held); None for an extra device."""
        if m.joint is None:
            return None
        return JointReading(
            q=float(self.data.qpos[self._qadr[m.joint]]),
            dq=float(self.data.qvel[self._dadr[m.joint]]),
            tau_raw=float(self._tau_raw[m.joint]),
        )

    def _reply(self, m: EmulatedMotor, frames: Sequence[framing.Frame], comm_type: int | None = None) -> None:
        """Send ``m``'s frames answering a ``comm_type`` request, honouring drop and silence (lock held)."""
        if m.interface in self._silent or fw.drop_reply(m, comm_type):
            return
        bus = self.buses[m.interface]
        for f in frames:
            bus.send(can.Message(arbitration_id=f[0], data=f[1], is_extended_id=True))

    def _feedback_frames(self, m: EmulatedMotor) -> list[framing.Frame]:
        return fw.feedback_frames(m, self._joint(m), self.temperature)

    def _garbage(self, interface: str) -> None:
        bus, rng = self.buses[interface], self._rng
        for _ in range(self.garbage_per_round):
            kind = rng.randrange(3)
            if kind == 0:  # a standard 11-bit frame
                msg = can.Message(
                    arbitration_id=rng.randrange(0x800), data=rng.randbytes(8), is_extended_id=False
                )
            elif kind == 1:  # a short extended frame
                msg = can.Message(arbitration_id=rng.randrange(1 << 29), data=rng.randbytes(rng.randrange(8)))
            else:  # an extended frame of an undefined communication type
                msg = can.Message(arbitration_id=(30 << 24) | rng.randrange(1 << 24), data=rng.randbytes(8))
            bus.send(msg)

    def _serve(self, interface: str, bus: can.BusABC) -> None:
        wait = 0.0
        while not self._stop.is_set():
            try:
                msg = bus.recv(timeout=wait)
            except can.CanError:
                return
            arrival = (msg.timestamp or self.clock()) if msg is not None else self.clock()
            with self._lock:  # trip what expired before this frame arrived; sleep at most to the next expiry
                wait = self._watchdog_pass(interface, arrival)
            if msg is None or msg.is_error_frame or msg.is_remote_frame:
                continue
            try:
                req = motor_side.decode_request(
                    msg.arbitration_id, msg.data, is_extended_id=msg.is_extended_id
                )
            except FrameError:
                continue  # not for a motor (another reply, garbage): firmware ignores it
            with self._lock:
                if interface in self._silent:
                    continue
                m = self.motors.get((interface, req.motor_id))
                if m is not None:
                    m.last_rx = arrival
                    self._handle(m, req)
                    if m.enabled and (w := fw.watchdog_window(m, self.watchdog_tick)) > 0:  # (re)armed
                        wait = min(wait, max(arrival + w - self.clock(), 0.0))

    # ----------------------------------------------------------------------------------------------
    # the watchdog (canTimeout)
    def _watchdog_pass(self, interface: str, now: float) -> float:
        """Trip every enabled motor on ``interface`` that heard nothing for its window before ``now``.

        Returns the seconds until the next armed watchdog expires (at most 50 ms, the stop poll).
        """
        wait, clock = 0.05, self.clock()
        for m in self._by_interface.get(interface, ()):
            if not m.enabled or (w := fw.watchdog_window(m, self.watchdog_tick)) <= 0:
                continue
            if not fw.watchdog_expired(m, now, w):
                wait = min(wait, m.last_rx + w - clock)
                continue
            trip = self.clock()
            fw.trip_watchdog(m, trip)
            self._commanded.discard((m.interface, m.can_id))
            log.info(
                "%s id %d (%s): canTimeout %.3f s expired (%.3f s since the last frame): reset mode",
                m.interface,
                m.can_id,
                m.name,
                w,
                trip - m.last_rx,
            )
            self._maybe_complete_round()
        return max(wait, 0.0)

    def _handle(self, m: EmulatedMotor, req: motor_side.Request) -> None:
        """The firmware's answer to one request (lock held); lockstep defers a round's type-1 replies."""
        if isinstance(req, motor_side.MitRequest):
            fw.apply_mit(m, req)
            if self.mode == "lockstep" and m.enabled and m.joint is not None:
                self._commanded.add((m.interface, m.can_id))
                self._pending.append((m, b""))
                self._maybe_complete_round()
                return
            self._reply(m, self._feedback_frames(m), framing.CommType.MIT)
            if self.garbage_per_round:
                self._garbage(m.interface)
            return
        frames = fw.handle_request(m, req, self._joint(m), self.temperature)
        if frames is not None:
            self._reply(m, frames, req.comm_type)
        if req.comm_type == framing.CommType.STOP:  # reset mode: this round no longer waits for this motor
            self._commanded.discard((m.interface, m.can_id))
            self._maybe_complete_round()

    def _maybe_complete_round(self) -> None:
        """Lockstep: step physics and answer once every enabled, audible joint motor was commanded."""
        if self.mode != "lockstep" or not self._pending:
            return
        due = {
            (m.interface, m.can_id)
            for m in self._joint_motors()
            if m.enabled and m.interface not in self._silent
        }
        if not due <= self._commanded:
            return
        if not self.frozen:
            self._step(self.n_substeps)
        pending, self._pending = self._pending, []
        self._commanded.clear()
        for m, _ in pending:
            self._reply(m, self._feedback_frames(m), framing.CommType.MIT)
        if self.garbage_per_round:
            for iface in {m.interface for m, _ in pending}:
                self._garbage(iface)
