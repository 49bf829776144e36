"""The identified model on an accelerator: predict, differentiate, forward dynamics, a residual.

    python scripts/check_device.py            # CUDA when present, else says so and uses the CPU
    python scripts/check_device.py --device cpu

A model identified on the simulated head (a short log, least squares) is moved to the device;
every check builds its inputs there and compares with the same computation on the CPU in
float64:

1. inverse dynamics ``tau = dynamics(q, qd, qdd)`` (float64 and float32);
2. the gradient of a loss with respect to theta and the joint states;
3. the mass matrix and the forward dynamics (``dynamics(q, qd, forward_dynamics(q, qd, tau))
   == tau``) and a short RK4 rollout;
4. 50 steps of training a zero-initialised residual network on top of the frozen model, which
   lowers the loss and leaves every tensor on the device.

Prints one line per check and exits 1 if any fails (0 when all pass).
"""

from __future__ import annotations

import argparse
import sys
import warnings

import torch

import torchjfa
from torchjfa.dynamics import rollout
from torchjfa.identification import IdentificationWarning
from torchjfa.learning import ResidualDynamics
from torchjfa.sim import generate_log

BATCH = 256


def _identified():
    sim = generate_log("head", n_samples=2100, seed=0, progress=False)
    log = torchjfa.data.JointLog(
        t=sim.t, q=sim.q, qd=sim.qd, tau=sim.tau, joint_names=sim.joint_names
    )
    options = torchjfa.Options(cutoff=15.0, jackknife=0, bias_correction=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentificationWarning)
        return torchjfa.identify("head", log, options)


def run(device: torch.device) -> bool:
    ident = _identified()
    cpu = ident.inverse_dynamics()
    dyn = ident.inverse_dynamics().to(device)
    n = cpu.model.n_dof
    g = torch.Generator().manual_seed(0)
    states = [torch.randn(BATCH, n, generator=g, dtype=torch.float64) for _ in range(3)]
    ok = True

    def report(name: str, passed: bool, detail: str) -> None:
        nonlocal ok
        ok &= passed
        print(f"{'ok  ' if passed else 'FAIL'} {name}: {detail}")

    ref = cpu(*states)
    for dtype, tol in ((torch.float64, 1e-10), (torch.float32, 1e-3)):
        q, qd, qdd = (s.to(device, dtype) for s in states)
        tau = dyn(q, qd, qdd)
        err = float((tau.double().cpu() - ref).abs().max() / ref.abs().max())
        where = tau.device.type == device.type and tau.dtype == dtype
        report(
            f"inverse dynamics {dtype}", where and err < tol, f"{err:.2e} relative, {tau.device}"
        )

    q, qd, qdd = (s.to(device).clone().requires_grad_(True) for s in states)
    trainable = ident.inverse_dynamics(trainable="unconstrained").to(device)
    trainable(q, qd, qdd).pow(2).mean().backward()
    grads = [trainable.theta.grad, q.grad, qd.grad, qdd.grad]
    finite = all(x is not None and bool(torch.isfinite(x).all()) for x in grads)
    report("gradients", finite and grads[0].device.type == device.type, "theta and states")

    q, qd, qdd = (s.to(device) for s in states)
    with torch.no_grad():
        tau = dyn(q, qd, qdd)
        back = dyn.forward_dynamics(q, qd, tau)
    err = float((back - qdd).abs().max() / qdd.abs().max())
    report(
        "forward dynamics", err < 1e-8, f"{err:.2e} relative, M {tuple(dyn.mass_matrix(q).shape)}"
    )
    with torch.no_grad():
        path_q, _ = rollout(dyn, q[0], 0 * qd[0], tau[:1].expand(50, -1), dt=1e-3, method="rk4")
    report(
        "rollout", bool(torch.isfinite(path_q).all()), f"{tuple(path_q.shape)} on {path_q.device}"
    )

    model = ResidualDynamics(ident.inverse_dynamics()).to(device)
    target = tau + 0.1 * torch.sin(q)  # what a residual has to learn
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-2)
    losses = []
    for _ in range(50):
        optimizer.zero_grad()
        loss = (model(q, qd, qdd) - target).pow(2).mean()
        loss.backward()
        optimizer.step()
        losses.append(float(loss.detach()))
    report(
        "residual training",
        losses[-1] < 0.5 * losses[0],
        f"loss {losses[0]:.3g} -> {losses[-1]:.3g}",
    )
    return ok


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="cuda, cpu, ... (default: cuda if present)")
    args = parser.parse_args(argv)
    if args.device is None:
        if not torch.cuda.is_available():
            print("no CUDA device here: the checks run on the CPU")
        args.device = "cuda" if torch.cuda.is_available() else "cpu"
    device = torch.device(args.device)
    print(
        f"device: {device}"
        + (f" ({torch.cuda.get_device_name(device)})" if device.type == "cuda" else "")
    )
    return 0 if run(device) else 1


if __name__ == "__main__":
    sys.exit(main())
