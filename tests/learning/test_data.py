"""`SimulatedLogDataModule`: the time split, the samples, the precomputed regressor."""

import pytest
import torch

from torchjfa.learning import SimulatedLogDataModule, log_tensors, time_split


@pytest.mark.parametrize("n, frac, chunk", [(1000, 0.2, 100), (1000, 0.25, 64), (10, 0.5, 1)])
def test_time_split_puts_whole_chunks_first_and_the_rest_after(n, frac, chunk):
    train, val = time_split(n, val_fraction=frac, chunk_size=chunk)
    assert train.start == 0 and train.stop == val.start and val.stop == n
    assert train.stop % chunk == 0
    assert train.stop <= (1 - frac) * n < train.stop + chunk


def test_time_split_rejects_bad_arguments():
    with pytest.raises(ValueError, match="val_fraction"):
        time_split(100, val_fraction=1.0, chunk_size=10)
    with pytest.raises(ValueError, match="chunk_size"):
        time_split(100, val_fraction=0.2, chunk_size=0)
    with pytest.raises(ValueError, match="too short"):
        time_split(10, val_fraction=0.05, chunk_size=10)
    assert time_split(7, val_fraction=0.0, chunk_size=3) == (slice(0, 7), slice(7, 7))


def test_samples_follow_the_log_in_time_with_their_regressor(head_files):
    log_path, id_path, log, model, _ = head_files
    dm = SimulatedLogDataModule(
        log_path,
        identified=id_path,
        val_fraction=0.25,
        chunk_size=64,
        batch_size=100,
        shuffle=False,
    )
    dm.setup("fit")
    n_train = len(dm.train_set)
    assert n_train == 448 and len(dm.val_set) == 640 - 448
    train = dm.train_tensors()
    assert torch.equal(train["q"], log.q[:n_train]) and torch.equal(train["tau"], log.tau[:n_train])
    assert torch.equal(dm.val_set.tensors["qdd"], log.qdd[n_train:])
    Y = model.regressor(log.q[n_train:], log.qd[n_train:], log.qdd[n_train:])
    torch.testing.assert_close(dm.val_set.tensors["Y"], Y, rtol=1e-12, atol=1e-12)
    batch = next(iter(dm.train_dataloader()))
    assert set(batch) == {"q", "qd", "qdd", "tau", "Y"}
    assert batch["Y"].shape == (100, 7, 77)
    assert torch.equal(batch["q"], log.q[:100])


def test_shuffling_stays_inside_the_training_part(head_files):
    log_path, *_ = head_files
    dm = SimulatedLogDataModule(
        log_path, val_fraction=0.5, chunk_size=32, batch_size=64, shuffle=True, seed=1
    )
    dm.setup("fit")
    seen = torch.cat([b["q"] for b in dm.train_dataloader()])
    train = dm.train_tensors()["q"]
    assert not torch.equal(seen, train)  # shuffled ...
    assert torch.equal(seen.sort(0).values, train.sort(0).values)  # ... the same samples
    assert "Y" not in dm.train_tensors()
    val = torch.cat([b["q"] for b in dm.val_dataloader()])
    assert torch.equal(val, dm.val_set.tensors["q"])


def test_n_train_and_signals(head_files):
    log_path, _, log, _, _ = head_files
    dm = SimulatedLogDataModule(log_path, n_train=100, signals="true", chunk_size=32)
    dm.setup("fit")
    assert torch.equal(dm.train_tensors()["tau"], log.tau_true[:100])
    assert torch.equal(dm.train_tensors()["qdd"], log.qdd_true[:100])
    q, _, _, tau = log_tensors(log, "measured_inputs", joint_names=log.joint_names[::-1])
    assert torch.equal(q, log.q.flip(-1)) and torch.equal(tau, log.tau_true.flip(-1))
    with pytest.raises(ValueError, match="n_train"):
        SimulatedLogDataModule(log_path, n_train=10_000, chunk_size=32).setup("fit")
    with pytest.raises(ValueError, match="signals"):
        SimulatedLogDataModule(log_path, signals="noisy")
    with pytest.raises(ValueError, match="batch_size"):
        SimulatedLogDataModule(log_path, batch_size=0)


def test_a_plain_joint_log_trains_as_its_simulated_log(head_files, tmp_path):
    """The data path takes any JointLog with accelerations: a write_log file of the measured
    signals alone gives the same samples, regressors and trained weights as the SimulatedLog."""
    from torchjfa.data import JointLog, write_log
    from torchjfa.learning import ResidualDynamicsModule

    from ._helpers import quiet_lightning, trainer

    log_path, id_path, log, _, _ = head_files
    plain = JointLog(
        t=log.t, q=log.q, qd=log.qd, qdd=log.qdd, tau=log.tau, joint_names=log.joint_names
    ).reorder(log.joint_names[::-1])  # columns in another order than the model's
    write_log(plain, tmp_path / "plain.npz")
    trained = []
    for path in (log_path, tmp_path / "plain.npz"):
        dm = SimulatedLogDataModule(
            path, identified=id_path, chunk_size=64, batch_size=64, shuffle=False
        )
        dm.setup("fit")
        torch.manual_seed(0)
        module = ResidualDynamicsModule(hidden=(8,), lr=1e-2, identified=str(id_path))
        with quiet_lightning():
            trainer(tmp_path / path.stem, max_epochs=2, num_sanity_val_steps=0).fit(module, dm)
        trained.append((dm.train_tensors(), torch.cat([p.flatten() for p in module.parameters()])))
    (a, wa), (b, wb) = trained
    assert all(torch.equal(a[k], b[k]) for k in ("q", "qd", "qdd", "tau", "Y"))
    assert torch.equal(wa, wb)
    torch.manual_seed(0)
    init = ResidualDynamicsModule(hidden=(8,), lr=1e-2, identified=str(id_path))
    assert not torch.equal(wa, torch.cat([p.flatten() for p in init.parameters()]))  # it trained


def test_a_joint_log_without_accelerations_must_be_prepared_first(head_files, tmp_path):
    from torchjfa.data import JointLog, write_log

    _, _, log, _, _ = head_files
    raw = JointLog(t=log.t, q=log.q, tau=log.tau, joint_names=log.joint_names)
    with pytest.raises(ValueError, match=r"no velocities; prepare it first"):
        log_tensors(raw)
    write_log(JointLog(t=log.t, q=log.q, qd=log.qd, tau=log.tau, joint_names=log.joint_names),
              tmp_path / "no_qdd.csv")  # fmt: skip
    with pytest.raises(ValueError, match=r"no_qdd.csv has no accelerations; prepare it first"):
        SimulatedLogDataModule(tmp_path / "no_qdd.csv", chunk_size=32).setup("fit")
    with_qdd = JointLog(
        t=log.t, q=log.q, qd=log.qd, qdd=log.qdd, tau=log.tau, joint_names=log.joint_names
    )
    with pytest.raises(ValueError, match="ground truth of a simulated log"):
        log_tensors(with_qdd, "true")
