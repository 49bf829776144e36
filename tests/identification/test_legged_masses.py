"""Which masses a floating-base log's rows see (`mass_spread`, `LeggedIdentification.
mass_in_span`): the total mass where the weight is measured, no single body's in a tree of
revolute joints, checked against the regrouping that moves a point mass across a joint without
changing any row."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import replace

import numpy as np
import pytest
import torch
from _robots import GO2_FEET, GO2_STANCE, erd_path

from torchjfa.dynamics import FloatingBaseModel
from torchjfa.identification import (
    IdentificationWarning,
    Options,
    contact_equations,
    identify_legged,
)
from torchjfa.identification._legged_masses import mass_index
from torchjfa.report import legged_markdown
from torchjfa.sim import simulate_legged

CUTOFF = 10.0


@pytest.fixture(scope="module")
def go2():
    path = erd_path("go2_description/urdf/go2.urdf")
    log = simulate_legged(path, GO2_FEET, GO2_STANCE, seconds=10.0, rate=100.0, perturb=0.2,
                          seed=1)  # fmt: skip
    return path, log


def test_a_point_mass_moved_across_a_joint_changes_no_row(go2):
    """The knee's axis passes through the calf frame's origin, 0.213 m below the thigh's
    (the URDF's joint origin): a point mass there, taken from the calf and given to the
    thigh, leaves every row of every sample as it was, so neither body's mass is in the span
    of the rows."""
    path, log = go2
    model = FloatingBaseModel.from_urdf(path, friction=())
    joint = ET.parse(path).getroot().find("joint[@name='FL_calf_joint']/origin")
    assert joint.get("rpy", "0 0 0").split() == ["0", "0", "0"]
    p = np.array([float(x) for x in joint.get("xyz").split()])  # the knee in the thigh frame
    bodies = ("base", *model.joints.body_names)
    thigh, calf = (10 * bodies.index(b) for b in ("FL_thigh", "FL_calf"))
    dm = 0.3  # kg
    delta = torch.zeros(model.n_params, dtype=torch.float64)
    delta[calf] = -dm  # at the calf's origin: no first moment, no inertia about it
    delta[thigh] = dm
    delta[thigh + 1 : thigh + 4] = torch.as_tensor(dm * p)  # the first moment m c
    inertia = dm * (p @ p * np.eye(3) - np.outer(p, p))  # about the thigh's origin
    delta[thigh + 4 : thigh + 10] = torch.as_tensor(inertia[[0, 0, 1, 0, 1, 2], [0, 1, 1, 2, 2, 2]])
    Y, _ = contact_equations(model, log.q, log.v, log.a, log.tau, wrenches=log.wrench)
    theta = torch.as_tensor(log.theta)
    scale = float((Y @ theta).abs().max())
    assert float((Y @ delta).abs().max()) < 1e-10 * scale
    assert float(delta[mass_index(model)].sum()) == 0.0  # the total mass is unchanged


def test_with_forces_the_rows_see_the_total_mass_and_no_single_body(go2):
    path, log = go2
    ident = identify_legged(path, log, Options(cutoff=CUTOFF))
    n_bodies = len(ident.masses())
    assert ident.mass_in_span.tolist() == [False] * n_bodies + [True]
    # noise-free rows: the total's jackknife spread is far under 1 % of it
    assert float(ident.mass_spread[-1]) < 0.01 * ident.total_mass
    text = legged_markdown(ident)
    total = next(line for line in text.splitlines() if line.startswith("| **total**"))
    cells = [c.strip() for c in total.split("|")]
    assert cells[5] == "yes" and float(cells[6]) > 0  # seen, with its spread
    body = next(line for line in text.splitlines() if line.startswith("| FL_calf |"))
    assert [c.strip() for c in body.split("|")][5:7] == ["no", "-"]
    assert "no single body's mass is seen" in text


def test_with_contact_flags_on_four_feet_the_rows_do_not_see_the_total_mass(go2):
    path, log = go2
    with pytest.warns(IdentificationWarning, match="weakly determined"):
        ident = identify_legged(path, replace(log, wrench={}), Options(cutoff=CUTOFF))
    # standing on four feet, the total mass is partly outside the projected rows' span
    assert not any(ident.mass_in_span.tolist())
