"""Refine what open-loop rollouts see and the regression does not, with MuJoCo's `mujoco.sysid`.

A rollout integrates the torques: it is moved by what a torque fit hardly pins down, MuJoCo's
dry-friction constraint (``frictionloss``), ``damping``, ``armature``, a delay between the
logged torque and the joint. `refine` starts from the identified model's MJCF export
(`mujoco_model`) and fits these per joint with `mujoco.sysid` (`Parameter`, `ModelSequences`,
`build_residual_fn`, `optimize`: Levenberg-Marquardt) on short windows of the training logs,
each rolled out from its measured state under its measured torques less the identified offsets,
held over each sample as `replay` does; the residual: the position error, and the velocity
error times ``velocity_weight``, at every sample.

The fit is judged by `replay` on held-out logs and kept only where those rollouts improve. With
the gain ``1 - err / err_identified`` of the held-out position RMS at each horizon:

* per joint: a joint's fitted values alone (the others as identified) are accepted when its own
  gain, averaged over the horizons, is at least ``min_gain`` and the mean over joints loses
  nothing on average; the delay alone when the mean over joints gains ``min_gain``;
* as a whole: the accepted ones together, and the whole fit, pass when the mean over joints
  gains at least ``min_gain`` averaged over the horizons and loses at most ``min_gain`` at any
  one; the better that passes is kept, else nothing (the identified values stay).

The delay is not in the MJCF (its rollouts are driven through ``qfrc_applied``): a delay ``d``
means the joint feels the logged torque of ``d`` s before; `Refinement.replay` shifts a log's
torques so. Joints a transmission drives keep their terms (they sit on its tendons).
Needs ``mujoco[sysid]`` (mujoco >= 3.5): ``pip install "torchjfa[sysid]"``.
"""

from __future__ import annotations

import copy
import io
import tempfile
import time
import xml.etree.ElementTree as ET
from collections import namedtuple
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import mujoco
import numpy as np
import torch

from ._replay import HORIZONS, Replay, _prepared, offset_torques, replay, substeps
from ._replay import _addresses as _address_lists

__all__ = ["PARAMETERS", "Refinement", "refine"]

#: what `refine` can fit: per joint, and one delay for every joint, s
PARAMETERS = ("frictionloss", "damping", "armature", "delay")
_FIELDS = {"frictionloss": "dof_frictionloss", "damping": "dof_damping", "armature": "dof_armature"}
_INSTALL = 'pip install "torchjfa[sysid]"'
_CAP = 10.0  # rad, rad/s: the cap on a rollout's error (a diverging candidate stays finite)


def _sysid():
    """`mujoco.sysid`, or an ImportError naming the extra (it imports without its dependencies,
    then without its names)."""
    try:
        from mujoco import sysid
        from mujoco.sysid._src import optimize  # noqa: F401  (names a missing dependency)
    except ImportError as exc:
        raise ImportError(f"refine needs mujoco.sysid (mujoco >= 3.5) and its extra's "
                          f"dependencies ({exc}): {_INSTALL}") from exc  # fmt: skip
    if not hasattr(sysid, "optimize"):
        raise ImportError(f"this mujoco.sysid has no optimize: {_INSTALL}")
    return sysid


@dataclass(frozen=True)
class Refinement:
    """What `refine` found, what it kept, and why.

    Attributes:
        mjcf: the refined MJCF: the identified export with the kept values written in.
        joint_names: ``(n_dof,)`` the logs' (and the model's) joints.
        parameters: what was fitted (from `PARAMETERS`).
        before, fitted, after: kind -> ``(n_dof,)`` the identified values (the fit's start),
            the fit's, and those kept (fitted where accepted, else identified).
        delay: ``(identified, fitted, kept)``, s (0 where the delay was not fitted).
        horizons: s.
        held_out: ``"before"``, ``"fitted"``, ``"after"`` -> ``(n_h, n_dof)`` the held-out
            rollouts' RMS position error, rad (mean over the held-out logs).
        accepted: the joints whose refined values were kept, and ``"delay"`` if it was.
        reasons: per joint, ``"delay"`` and ``"whole"``: the verdict in words.
        fit: the fit's figures (windows, iterations, model builds, costs, seconds).
        offset: ``(n_dof,)`` the identified constant torques taken off the drive, N m.
    """

    mjcf: str
    joint_names: tuple[str, ...]
    parameters: tuple[str, ...]
    before: dict[str, np.ndarray]
    fitted: dict[str, np.ndarray]
    after: dict[str, np.ndarray]
    delay: tuple[float, float, float]
    horizons: tuple[float, ...]
    held_out: dict[str, np.ndarray]
    accepted: tuple[str, ...]
    reasons: dict[str, str]
    fit: dict = field(default_factory=dict)
    offset: np.ndarray | None = None

    def model(self) -> mujoco.MjModel:
        """The refined MuJoCo model, contacts and actuators off (as `mujoco_model`)."""
        with tempfile.TemporaryDirectory() as tmp:
            (path := Path(tmp) / "refined.xml").write_text(self.mjcf, encoding="utf-8")
            return _prepared(mujoco.MjModel.from_xml_path(str(path)))

    def replay(self, log, **kwargs) -> Replay:
        """`replay` of the refined model (as ``"refined"``) on a prepared ``log`` whose torques
        are shifted by the kept delay, less the offsets; ``kwargs`` go to `replay`."""
        log = log.reorder(self.joint_names)
        if self.delay[2] != 0.0:
            log = replace(log, tau=torch.from_numpy(_shifted(log, self.delay[2])))
        offset = np.zeros(len(self.joint_names)) if self.offset is None else self.offset
        return replay({"refined": self.model()}, log, offsets={"refined": offset}, **kwargs)

    def summary(self) -> dict[str, object]:
        """JSON-ready."""
        out = {k: getattr(self, k) for k in ("parameters", "joint_names", "delay", "horizons",
                                             "accepted", "reasons", "fit")}  # fmt: skip
        for k in ("before", "fitted", "after", "held_out"):
            out[k] = {n: v.tolist() for n, v in getattr(self, k).items()}
        return {k: list(v) if isinstance(v, tuple) else v for k, v in out.items()}

    def lines(self) -> list[str]:
        """The values per joint (identified -> fitted, kept or not) and the held-out errors."""
        kinds = [k for k in self.parameters if k != "delay"]
        rows = [f"{'joint':<22}" + "".join(f"{k + ' (id -> fit)':>30}" for k in kinds) + "  kept"]
        rows = rows if kinds else []
        for j, name in enumerate(self.joint_names if kinds else ()):
            cells = "".join(f"{self.before[k][j]:>14.4g} -> {self.fitted[k][j]:<12.4g}"
                            for k in kinds)  # fmt: skip
            rows.append(f"{name:<22}{cells}  {'yes' if name in self.accepted else 'no'}")
        if "delay" in self.parameters:
            kept = "yes" if "delay" in self.accepted else "no"
            rows.append(f"{'delay, s':<22}{self.delay[0]:>14.4g} -> {self.delay[1]:<12.4g}  {kept}")
        rows.append(f"{'held-out rollouts':<22}" + "".join(f"{h:>10.3g} s" for h in self.horizons))
        for k, err in self.held_out.items():
            rows.append(f"{'  ' + k + ', rad':<22}" + "".join(f"{e:>12.4g}" for e in err.mean(1)))
        rows += [f"  {k}: {v}" for k, v in self.reasons.items() if k in ("whole", "delay")]
        return rows


_Window = namedtuple("_Window", "log start samples n_sub timestep")


def _windows(logs, window: float, max_windows: int, timestep: float) -> list[_Window]:
    """Up to ``max_windows`` windows of ``window`` s spread evenly over the logs, in proportion
    to their lengths, overlapping only where the logs are too short to hold them apart."""
    periods = [float(np.median(np.diff(log.t.numpy()))) for log in logs]
    spans = [(max(1, round(window / p)), substeps(p, timestep), p) for p in periods]
    free = [max(0, log.n_samples - 1 - k) for (k, _, _), log in zip(spans, logs, strict=True)]
    if sum(free) == 0:
        raise ValueError(f"no training log is longer than the {window} s window")
    out = []
    for i, ((k, n_sub, period), f) in enumerate(zip(spans, free, strict=True)):
        n = max(1, round(max_windows * f / sum(free))) if f else 0
        starts = np.unique(np.linspace(0, f, n).astype(int))
        out += [_Window(i, int(s), k, n_sub, period / n_sub) for s in starts]
    return out


def _addresses(mj: mujoco.MjModel, joints: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """``(qpos addresses, dof addresses)`` of ``joints`` as arrays."""
    return tuple(np.array(a) for a in _address_lists(mj, joints))


def _sysid_spec(path: str, joints: Sequence[str], timestep: float) -> mujoco.MjSpec:
    """The exported model for `mujoco.sysid`: one unlimited gear-1 motor per joint (``ctrl`` the
    joint torque) in place of its actuators, joint position then velocity sensors in place of
    its sensors, contacts off, the given timestep."""
    spec = mujoco.MjSpec.from_file(path)
    for element in [*spec.actuators, *spec.sensors]:
        spec.delete(element)
    for j in joints:
        spec.joint(j).actfrclimited = mujoco.mjtLimited.mjLIMITED_FALSE
        a = spec.add_actuator(name=f"refine_{j}", target=j, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        a.ctrllimited = a.forcelimited = mujoco.mjtLimited.mjLIMITED_FALSE
    sensors = (mujoco.mjtSensor.mjSENS_JOINTPOS, mujoco.mjtSensor.mjSENS_JOINTVEL)
    for n, (kind, j) in enumerate([(kind, j) for kind in sensors for j in joints]):
        spec.add_sensor(name=f"refine{n}", type=kind, objtype=mujoco.mjtObj.mjOBJ_JOINT, objname=j)
    spec.option.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    spec.option.timestep = timestep
    return spec


def _upper_bounds(mj, dof, logs, offset, start: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per kind ``(n_dof,)`` the fit's upper bound: 3x the identified value, at least half the
    RMS training torque (friction loss), half of it over the RMS velocity (damping), the mean
    joint-space inertia ``M_jj`` over training states (armature)."""
    tau = np.concatenate([log.tau.numpy() for log in logs]) - offset
    qd = np.concatenate([log.qd.numpy() for log in logs])
    tau_rms = np.maximum(np.sqrt(np.mean(tau**2, axis=0)), 1e-6)
    data, m_jj, out = mujoco.MjData(mj), np.zeros(len(dof)), np.zeros(mj.nv)
    qadr, _ = _addresses(mj, logs[0].joint_names)
    for log in logs:
        for s in np.linspace(0, log.n_samples - 1, 8).astype(int):
            data.qpos[qadr] = log.q[s].numpy()
            mujoco.mj_forward(mj, data)
            for j, d in enumerate(dof):
                mujoco.mj_mulM(mj, data, out, np.eye(mj.nv)[d])
                m_jj[j] += out[d] / (8 * len(logs))
    floor = {"frictionloss": 0.5 * tau_rms, "armature": m_jj,
             "damping": 0.5 * tau_rms / np.maximum(np.sqrt(np.mean(qd**2, axis=0)), 1e-6)}  # fmt: skip
    return {k: np.maximum(3.0 * start[k], floor[k]) for k in start}


class _Problem:
    """The windows, the sysid model sequences and parameters of one refinement."""

    def __init__(self, sysid, path, start_mj, joints, free, kinds, logs, offset, opts):
        self.sysid, self.joints, self.free, self.kinds = sysid, tuple(joints), free, kinds
        self.logs, self.offset, self.velocity_weight = logs, offset, opts["velocity_weight"]
        _, self.dof = _addresses(start_mj, joints)
        self.start = {k: np.array(getattr(start_mj, _FIELDS[k])[self.dof]) for k in kinds}
        self.upper = _upper_bounds(start_mj, self.dof, logs, offset, self.start)
        timestep = float(start_mj.opt.timestep)
        self.windows = _windows(logs, opts["window"], opts["max_windows"], timestep)
        self.bases, self.sources, self.sequences = {}, {}, []
        for step in sorted({round(w.timestep, 12) for w in self.windows}):
            group = [w for w in self.windows if round(w.timestep, 12) == step]
            spec = _sysid_spec(path, joints, group[0].timestep)
            self.bases[id(spec)] = base = spec.compile()
            self.sequences.append(self._sequences(spec, base, group))
        self.params = self._parameters(opts["max_delay"])
        self.cache: dict[tuple, mujoco.MjModel] = {}
        self.evaluations = 0

    def _sequences(self, spec, base, group):
        qadr, dadr = _addresses(base, self.joints)
        names, states, controls, sensed = [], [], [], []
        for w in group:
            log, s, k = self.logs[w.log], w.start, w.samples
            t, q, qd = log.t.numpy(), log.q.numpy(), log.qd.numpy()
            drive = self.drive(w, 0.0)
            dt = (t[s + k] - t[s]) / (k * w.n_sub)
            controls.append(self.sysid.TimeSeries(t[s] + dt * np.arange(len(drive)), drive))
            self.sources[id(controls[-1])] = w
            qpos, qvel = base.qpos0.copy(), np.zeros(base.nv)
            qpos[qadr], qvel[dadr] = q[s], qd[s]
            states.append(self.sysid.create_initial_state(base, qpos, qvel))
            measured = np.hstack([q[s : s + k + 1], qd[s : s + k + 1]])
            sensed.append(self.sysid.TimeSeries.from_names(t[s : s + k + 1], measured, base))
            names.append(f"log{w.log}@{s}")
        return self.sysid.ModelSequences(f"refine{len(self.sequences)}", spec, names, states,
                                         controls, sensed)  # fmt: skip

    def drive(self, w: _Window, delay: float) -> np.ndarray:
        """A window's torques ``delay`` s earlier, less the offsets, held over each sample's
        physics steps (and one more row: the rollout drops the last)."""
        rows = slice(w.start, w.start + w.samples)
        tau = _shifted(self.logs[w.log], delay, rows) - self.offset
        return np.vstack([np.repeat(tau, w.n_sub, axis=0), tau[-1:]])

    def _parameters(self, max_delay: float):
        """Per free joint and kind the value over its upper bound, in [0, 1]; the delay, s."""
        params = self.sysid.ParameterDict()
        for j in self.free:
            for k in self.kinds:
                x0 = self.start[k][j] / self.upper[k][j]
                params.add(self.sysid.Parameter(f"{self.joints[j]}/{k}", x0, 0.0, 1.0))
        if max_delay > 0:
            params.add(self.sysid.Parameter("delay", 0.0, -max_delay, max_delay))
        return params

    def values(self, params) -> tuple[dict[str, np.ndarray], float]:
        """The physical values of ``params``: kind -> ``(n_dof,)``, and the delay, s."""
        out = {k: v.copy() for k, v in self.start.items()}
        for j in self.free:
            for k in self.kinds:
                out[k][j] = float(params[f"{self.joints[j]}/{k}"].value[0]) * self.upper[k][j]
        delay = float(params["delay"].value[0]) if "delay" in params else 0.0
        return out, delay

    def build(self, params, spec) -> mujoco.MjModel:
        """sysid's build_model: the window group's compiled model with the values set."""
        key = (id(spec), params.as_vector().tobytes())
        if key not in self.cache:
            if len(self.cache) > 256:
                self.cache.clear()
            self.cache[key] = _with(self.bases[id(spec)], self.dof, self.values(params)[0])
        self.evaluations += 1
        return self.cache[key]

    def residual(self, params, predicted, measured, model, return_pred_all, state, **_):
        """sysid's modify_residual: the measured samples against the rollout's state at the same
        times (after every n_sub-th physics step; its sensors read the state before a step),
        velocities weighted by ``velocity_weight``."""
        k = len(measured.times) - 1
        qadr, dadr = _addresses(model, self.joints)
        rows = state[(len(state) // k) * np.arange(1, k + 1) - 1]
        pred = np.hstack([rows[:, 1 + qadr], rows[:, 1 + model.nq + dadr]])
        meas = measured.data[1:]
        err = np.clip(np.nan_to_num(pred - meas, nan=_CAP), -_CAP, _CAP)
        err[:, len(self.joints) :] *= self.velocity_weight
        ts = self.sysid.TimeSeries
        return (err.ravel(), ts(measured.times[1:], pred, measured.signal_mapping),
                ts(measured.times[1:], meas, measured.signal_mapping))  # fmt: skip

    def delayed_rollout(self, models, datas, control_signal, initial_states, param_dicts, **maps):
        """sysid's custom_rollout: each window's drive read ``delay`` s earlier in its log."""
        per = len(control_signal) // len(param_dicts)
        controls = []
        for i, ctrl in enumerate(control_signal):
            delay = float(param_dicts[i // per]["delay"].value[0])
            drive = self.drive(self.sources[id(ctrl)], delay)
            controls.append(self.sysid.TimeSeries(ctrl.times, drive, ctrl.signal_mapping))
        return self.sysid.sysid_rollout(models, datas, controls, initial_states, **maps)


def _with(mj: mujoco.MjModel, dof, values: dict[str, np.ndarray]) -> mujoco.MjModel:
    """A copy of ``mj`` with ``values`` (kind -> ``(n_dof,)``) at the dofs ``dof``, its derived
    constants recomputed (the constraints' softness depends on the armature) as compiling the
    MJCF would."""
    mj = copy.copy(mj)
    for k, v in values.items():
        getattr(mj, _FIELDS[k])[dof] = v
    mujoco.mj_setConst(mj, mujoco.MjData(mj))
    return mj


def _shifted(log, delay: float, rows=slice(None)) -> np.ndarray:
    """The log's torque at its samples ``rows``, ``delay`` s earlier (linear between samples,
    held at the ends)."""
    t, tau = log.t.numpy(), log.tau.numpy()
    if delay == 0.0:
        return tau[rows]
    return np.stack([np.interp(t[rows] - delay, t, col) for col in tau.T], axis=1)


def _fit(problem: _Problem, max_iters: int, fd_eps: float):
    """`mujoco.sysid.optimize` from the identified values: ``(params, figures)``."""
    from absl import logging as absl_logging  # a dependency of mujoco[sysid]

    sysid = problem.sysid
    kwargs = {"models_sequences": problem.sequences, "build_model": problem.build,
              "modify_residual": problem.residual, "n_threads": 1, "resample_true": False}  # fmt: skip
    if "delay" in problem.params:
        kwargs["custom_rollout"] = problem.delayed_rollout
    residual_fn = sysid.build_residual_fn(**kwargs)
    started, level = time.perf_counter(), absl_logging.get_verbosity()
    absl_logging.set_verbosity(absl_logging.ERROR)  # not its warning of a value at a bound
    try:
        params, result = sysid.optimize(problem.params, residual_fn, optimizer="mujoco",
                                        verbose=False, max_iters=max_iters,
                                        output=io.StringIO(), eps=fd_eps)  # fmt: skip
    finally:
        absl_logging.set_verbosity(level)
    cost = list(result.extras.get("objective", [])) or [float("nan")]
    windows = problem.windows
    return params, {"windows": len(windows), "parameters": int(problem.params.size),
                    "window_s": float(np.mean([w.samples * w.n_sub * w.timestep for w in windows])),
                    "iterations": len(cost), "model_builds": problem.evaluations,
                    "cost_start": float(cost[0]), "cost_end": float(min(cost)),
                    "seconds": time.perf_counter() - started}  # fmt: skip


def _judge(start_mj, dof, logs, offset, horizons, starts):
    """``judge(values, delay)``: `replay` of the starting model with other values on the held-out
    logs (torques shifted by ``delay``): ``(n_h, n_dof)`` the RMS position error, mean over them."""
    timestep = float(start_mj.opt.timestep)

    def judge(values: dict[str, np.ndarray], delay: float) -> np.ndarray:
        errors = []
        for log in logs:
            mj = _with(start_mj, dof, values)
            mj.opt.timestep = timestep  # replay sets its own
            log = log if delay == 0.0 else replace(log, tau=torch.from_numpy(_shifted(log, delay)))
            r = replay({"m": mj}, log, horizons=horizons, starts=starts, offsets={"m": offset})
            errors.append(r.position["m"])
            judge.calls += 1
        return np.mean(errors, axis=0)

    judge.calls, judge.horizons = 0, tuple(float(h) for h in horizons)
    return judge


def _gain(err: np.ndarray, before: np.ndarray, whole: bool = False) -> np.ndarray:
    """``1 - err / before`` (0 where ``before`` is 0); of the means over joints with ``whole``."""
    if whole:
        err, before = err.mean(axis=1), before.mean(axis=1)
    return 1.0 - np.divide(err, before, out=np.ones_like(err), where=before > 0)


def _mix(start: dict, fitted: dict, joints: list[int]) -> dict[str, np.ndarray]:
    """``start`` with ``fitted``'s values at the joints (indices) ``joints``."""
    out = {k: v.copy() for k, v in start.items()}
    for k in out:
        out[k][joints] = fitted[k][joints]
    return out


def _one_by_one(problem, judge, fitted, delay, before, min_gain):
    """Each free joint's fitted values alone, and the delay alone: ``(accepted, reasons)``."""
    accepted, reasons = [], {}
    for j in problem.free:
        name = problem.joints[j]
        values = _mix(problem.start, fitted, [j])
        if all(np.isclose(values[k][j], problem.start[k][j], rtol=1e-9) for k in values):
            reasons[name] = "the fit left it as identified"
            continue
        err = judge(values, 0.0)
        own, mean = _gain(err[:, j], before[:, j]).mean(), _gain(err, before, True).mean()
        ok = own >= min_gain and mean >= 0.0
        accepted += [name] if ok else []
        reasons[name] = (f"alone: its own held-out error x{1 - own:.3g}, the mean over joints "
                         f"x{1 - mean:.3g}: {'accepted' if ok else 'rejected'}")  # fmt: skip
    if "delay" in problem.params:
        mean = _gain(judge(problem.start, delay), before, True).mean()
        ok = mean >= min_gain
        accepted += ["delay"] if ok else []
        reasons["delay"] = (f"{delay * 1e3:.3g} ms alone: the mean held-out error over joints "
                            f"x{1 - mean:.3g}: {'accepted' if ok else 'rejected'}")  # fmt: skip
    return accepted, reasons


def _accept(problem, judge, fitted, delay, min_gain):
    """The per-joint and whole verdicts on the held-out rollouts: ``(kept values, kept delay,
    accepted, reasons, held-out errors)``."""
    before, full = judge(problem.start, 0.0), judge(fitted, delay)
    accepted, reasons = _one_by_one(problem, judge, fitted, delay, before, min_gain)
    candidates = []
    if accepted:
        values = _mix(problem.start, fitted, [problem.joints.index(j) for j in accepted
                                              if j != "delay"])  # fmt: skip
        kept_delay = delay if "delay" in accepted else 0.0
        combined = judge(values, kept_delay)
        candidates.append(("the accepted joints together", values, kept_delay, combined, accepted))
    changed = [problem.joints[j] for j in problem.free
               if any(not np.isclose(fitted[k][j], problem.start[k][j]) for k in fitted)]  # fmt: skip
    changed += ["delay"] if "delay" in problem.params and delay != 0.0 else []
    candidates.append(("the whole fit", fitted, delay, full, changed))
    verdicts, best = [], None
    for name, values, d, err, joints in candidates:
        gains = _gain(err, before, True)
        ok = bool(gains.mean() >= min_gain and gains.min() >= -min_gain)
        verdicts.append(f"{name}: mean held-out error over joints "
                        + ", ".join(f"x{1 - g:.3g}" for g in gains) + (" (passes)" if ok else ""))  # fmt: skip
        if ok and (best is None or gains.mean() > best[0]):
            best = (gains.mean(), name, values, d, err, joints)
    if best is None:
        reasons["whole"] = "; ".join(verdicts) + ": nothing kept, the identified values stay"
        return problem.start, 0.0, (), reasons, {"before": before, "fitted": full, "after": before}
    _, name, values, d, err, joints = best
    reasons["whole"] = "; ".join(verdicts) + f": {name} kept"
    return values, d, tuple(joints), reasons, {"before": before, "fitted": full, "after": err}


def _written(text: str, joints, values: dict[str, np.ndarray], which) -> str:
    """The MJCF ``text`` with ``values`` written into the joints ``which``."""
    root = ET.fromstring(text, parser=ET.XMLParser(target=ET.TreeBuilder(insert_comments=True)))
    by_name = {el.get("name"): el for el in root.iter("joint")}
    for j, name in enumerate(joints):
        if name in which:
            for k, v in values.items():
                by_name[name].set(k, f"{float(v[j]):.17g}")
    return ET.tostring(root, encoding="unicode") + "\n"


def _ready(logs, model) -> list:
    """The logs as a list, their joints in the model's order, each with velocities."""
    logs = [logs] if hasattr(logs, "joint_names") else list(logs)
    if not logs:
        raise ValueError("refine needs at least one training and one held-out log")
    for log in logs:
        if log.qd is None:
            raise ValueError(f"{log.source}: rollouts start from measured states: no velocities")
    return [log.reorder(model.joint_names) for log in logs]


def _free(model, joints) -> list[int]:
    """The indices of ``joints`` (default all) less those a transmission drives."""
    names, driven = list(model.joint_names), set(getattr(model.transmission, "joints", ()))
    unknown = [j for j in joints or () if j not in names]
    if unknown:
        raise ValueError(f"the model has no joints {unknown}")
    return [names.index(j) for j in (joints or names) if j not in driven]


def refine(model, theta, logs_train, logs_held_out, *,
           parameters: Sequence[str] = ("frictionloss", "damping", "armature"),
           joints: Sequence[str] | None = None, window: float = 0.2, max_windows: int = 64,
           velocity_weight: float = 0.05, max_delay: float = 0.02, max_iters: int = 30,
           min_gain: float = 0.02, horizons: Sequence[float] = HORIZONS, starts: int = 40,
           fd_eps: float = 1e-4) -> Refinement:  # fmt: skip
    """Refine the identified model's joint terms on rollouts with `mujoco.sysid`, keeping what
    held-out rollouts confirm (see the module).

    Args:
        model: the identified `torchjfa.dynamics.RigidBodyModel`.
        theta: its physically consistent ``(n_params,)`` parameters (the MJCF export's).
        logs_train: prepared `torchjfa.data.JointLog` s (q, qd, the measured tau, evenly
            sampled, as `replay` takes them), or one: the fit's.
        logs_held_out: the same, the judge's.
        parameters: from `PARAMETERS`: the per-joint terms to fit, and ``"delay"``.
        joints: the joints to fit (default: all but those a transmission drives).
        window: the fit's rollouts' length, s.
        max_windows: the fit's rollouts, spread over the training logs.
        velocity_weight: the velocity error's weight in the residual, s.
        max_delay: the delay's bound (either sign), s.
        max_iters: Levenberg-Marquardt iterations.
        min_gain: the held-out improvement to accept, a fraction (see the module).
        horizons: the judge's horizons, s.
        starts: the judge's rollouts per horizon and log.
        fd_eps: the finite-difference step on the scaled values (in [0, 1]).

    Raises:
        ImportError: without the ``mujoco[sysid]`` extra (``pip install "torchjfa[sysid]"``).
        ValueError: on unknown parameters or joints, logs without velocities or too short.
    """
    sysid = _sysid()
    parameters = tuple(dict.fromkeys(parameters))
    unknown = [p for p in parameters if p not in PARAMETERS]
    if unknown or not parameters:
        raise ValueError(f"parameters must be some of {PARAMETERS}, got {list(parameters)}")
    kinds = [k for k in _FIELDS if k in parameters]
    train, held = _ready(logs_train, model), _ready(logs_held_out, model)
    offset = offset_torques(model, theta)
    opts = {"window": float(window), "max_windows": int(max_windows),
            "velocity_weight": float(velocity_weight),
            "max_delay": float(max_delay) if "delay" in parameters else 0.0}  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        path = str(Path(tmp) / "identified.xml")
        model.write_mjcf(theta, path)
        text = Path(path).read_text(encoding="utf-8")
        start_mj = _prepared(mujoco.MjModel.from_xml_path(path))
        free = _free(model, joints)
        problem = _Problem(sysid, path, start_mj, model.joint_names, free, kinds, train, offset,
                           opts)  # fmt: skip
    params, figures = _fit(problem, int(max_iters), float(fd_eps))
    fitted, delay = problem.values(params)
    delay = delay if abs(delay) > 1e-6 else 0.0  # under a microsecond: none
    judge = _judge(start_mj, problem.dof, held, offset, horizons, starts)
    started = time.perf_counter()
    after, kept_delay, accepted, reasons, held_out = _accept(problem, judge, fitted, delay,
                                                             float(min_gain))  # fmt: skip
    figures.update(judge_rollouts=judge.calls, judge_seconds=time.perf_counter() - started)
    mjcf = _written(text, model.joint_names, after, set(accepted))
    return Refinement(mjcf, tuple(model.joint_names), parameters, problem.start, fitted, after,
                      (0.0, delay, kept_delay), judge.horizons, held_out, accepted, reasons,
                      figures, offset)  # fmt: skip
