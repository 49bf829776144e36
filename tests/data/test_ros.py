"""Reading joint logs from ROS bags: bags written with rosbags' own writers, read back exactly."""

import shutil
import sqlite3
import sys

import numpy as np
import pytest

from torchjfa.data import LogError
from torchjfa.data._ros import ros_columns

rosbag1 = pytest.importorskip("rosbags.rosbag1")
rosbag2 = pytest.importorskip("rosbags.rosbag2")
typesys = pytest.importorskip("rosbags.typesys")

JOINTS = ("shoulder", "elbow", "wrist")
JS = "sensor_msgs/msg/JointState"
START_NS = 1_700_000_000_123_456_789  # a stamp since 1970: float64 seconds would lose its ns
STEP_NS = 1_000_000  # 1 kHz


def _trajectory(n=120, joints=JOINTS, seed=0):
    """Sinusoids per joint: stamps (int ns), positions, velocities, torques ``(n, n_dof)``."""
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    stamps = START_NS + k * STEP_NS + rng.integers(0, 1000, n)  # a jittery clock
    s = (stamps - stamps[0]) / 1e9
    f = 0.5 + np.arange(len(joints))
    q = np.sin(2 * np.pi * f * s[:, None] + 1.0)
    qd = 2 * np.pi * f * np.cos(2 * np.pi * f * s[:, None] + 1.0)
    tau = 3.0 * q + 0.1 * rng.standard_normal(q.shape)
    return stamps, q, qd, tau


def _expected(stamps, q, qd, tau, joints=JOINTS, effort="tau"):
    cols = {"t": (stamps - stamps[0]).astype(np.float64) / 1e9}
    for prefix, v in (("q", q), ("qd", qd), (effort, tau)):
        if v is not None:
            cols.update({f"{prefix}_{j}": v[:, i] for i, j in enumerate(joints)})
    return cols


def _assert_columns(got, want):
    assert list(got) == list(want)
    for name, v in want.items():
        assert got[name].dtype == np.float64 and got[name].shape == v.shape, name
        np.testing.assert_array_equal(got[name], v, err_msg=name)


def _store(kind):
    stores = typesys.Stores
    return typesys.get_typestore(stores.ROS1_NOETIC if kind == "ros1" else stores.ROS2_HUMBLE)


def _joint_state(store, stamp_ns, names, q, qd=(), effort=()):
    types = store.types
    header = types["std_msgs/msg/Header"]
    extra = {"seq": 0} if "seq" in header.__dataclass_fields__ else {}  # ROS 1
    stamp = types["builtin_interfaces/msg/Time"](
        sec=int(stamp_ns) // 1_000_000_000, nanosec=int(stamp_ns) % 1_000_000_000
    )
    return types[JS](
        header=header(stamp=stamp, frame_id="base", **extra),
        name=list(names),
        position=np.asarray(q, dtype=np.float64),
        velocity=np.asarray(qd, dtype=np.float64),
        effort=np.asarray(effort, dtype=np.float64),
    )


def _write_bag(path, kind, topics):
    """A bag of ``kind`` ("sqlite3", "mcap", "ros1") with ``topics``: topic -> (type,
    [(receive ns, message)]) where a message is a JointState field dict or, for another type,
    the message object; returns the path to read."""
    store = _store(kind)
    if kind == "ros1":
        path = path.with_suffix(".bag")
        writer = rosbag1.Writer(path)
        serialize = store.serialize_ros1
    else:
        plugin = rosbag2.StoragePlugin[kind.upper()]
        writer = rosbag2.Writer(path, version=9, storage_plugin=plugin)
        serialize = store.serialize_cdr
    with writer:
        records = []
        for topic, (msgtype, messages) in topics.items():
            connection = writer.add_connection(topic, msgtype, typestore=store)
            for received, msg in messages:
                if msgtype == JS:
                    msg = _joint_state(store, **msg)
                records.append((received, connection, serialize(msg, msgtype)))
        for received, connection, data in sorted(records, key=lambda r: r[0]):
            writer.write(connection, received, data)
    return path


def _messages(stamps, q, qd, tau, joints=JOINTS, latency_ns=200_000):
    """JointState field dicts, received ``latency_ns`` after their stamps."""
    return [
        (
            int(s) + latency_ns,
            dict(
                stamp_ns=int(s), names=joints, q=q[k], qd=() if qd is None else qd[k], effort=tau[k]
            ),
        )
        for k, s in enumerate(stamps)
    ]


@pytest.mark.parametrize("kind", ["sqlite3", "mcap", "ros1"])
def test_every_bag_format_reads_back_exactly(tmp_path, kind):
    stamps, q, qd, tau = _trajectory()
    path = _write_bag(
        tmp_path / "bag", kind, {"/joint_states": (JS, _messages(stamps, q, qd, tau))}
    )
    _assert_columns(ros_columns(path), _expected(stamps, q, qd, tau))


@pytest.mark.parametrize("kind", ["sqlite3", "mcap"])
def test_a_storage_file_reads_in_its_folder_and_alone(tmp_path, kind):
    stamps, q, qd, tau = _trajectory()
    bag = _write_bag(tmp_path / "bag", kind, {"/joint_states": (JS, _messages(stamps, q, qd, tau))})
    (storage,) = [p for p in bag.iterdir() if p.suffix in (".db3", ".mcap")]
    alone = tmp_path / f"alone{storage.suffix}"
    shutil.copy(storage, alone)
    want = _expected(stamps, q, qd, tau)
    _assert_columns(ros_columns(storage), want)
    _assert_columns(ros_columns(alone), want)


def test_a_bag_without_message_definitions_uses_the_standard_types(tmp_path):
    """ROS 2 Humble's SQLite3 bags store no message definitions."""
    stamps, q, qd, tau = _trajectory()
    bag = _write_bag(
        tmp_path / "bag", "sqlite3", {"/joint_states": (JS, _messages(stamps, q, qd, tau))}
    )
    (db,) = bag.glob("*.db3")
    with sqlite3.connect(db) as con:
        con.execute("DELETE FROM message_definitions")
    con.close()
    _assert_columns(ros_columns(bag), _expected(stamps, q, qd, tau))


def test_joints_are_matched_by_name_whatever_their_order(tmp_path):
    stamps, q, qd, tau = _trajectory(seed=1)
    rng = np.random.default_rng(2)
    first = (2, 0, 1)  # the first message's order is the columns' order
    messages = []
    for k, s in enumerate(stamps):
        p = np.array(first if k == 0 else rng.permutation(3))
        names = [JOINTS[i] for i in p]
        messages.append(
            (int(s), dict(stamp_ns=int(s), names=names, q=q[k, p], qd=qd[k, p], effort=tau[k, p]))
        )
    assert len({tuple(m["names"]) for _, m in messages}) == 6  # every order occurs
    path = _write_bag(tmp_path / "bag", "mcap", {"/joint_states": (JS, messages)})
    p = list(first)
    want = _expected(stamps, q[:, p], qd[:, p], tau[:, p], joints=[JOINTS[i] for i in p])
    _assert_columns(ros_columns(path), want)


def test_messages_naming_other_joints_are_dropped_with_a_note(tmp_path, notes):
    """A gripper driver publishing on the arm's topic: the arm's (more) messages are read."""
    stamps, q, qd, tau = _trajectory()
    gripper = [
        (
            int(s) + 500_000,
            dict(stamp_ns=int(s) + 500_000, names=["finger"], q=[0.01], effort=[2.0]),
        )
        for s in stamps[::10]
    ]
    path = _write_bag(
        tmp_path / "bag", "mcap", {"/joint_states": (JS, _messages(stamps, q, qd, tau) + gripper)}
    )
    _assert_columns(ros_columns(path), _expected(stamps, q, qd, tau))
    (message,) = [r.getMessage() for r in notes.records]
    assert "dropped the other 12" in message and "finger" in message


def test_zero_stamps_fall_back_to_the_receive_time(tmp_path, notes):
    stamps, q, qd, tau = _trajectory()
    messages = [
        (int(s), dict(m, stamp_ns=0))
        for s, (_, m) in zip(stamps, _messages(stamps, q, qd, tau), strict=True)
    ]
    path = _write_bag(tmp_path / "bag", "sqlite3", {"/joint_states": (JS, messages)})
    _assert_columns(ros_columns(path), _expected(stamps, q, qd, tau))
    assert any("header stamp is zero" in r.getMessage() for r in notes.records)


def test_repeated_stamps_are_kept_for_the_log_reader_to_report(tmp_path):
    stamps, q, qd, tau = _trajectory(n=10)
    stamps[5] = stamps[4]  # a republished message
    path = _write_bag(
        tmp_path / "bag", "mcap", {"/joint_states": (JS, _messages(stamps, q, qd, tau))}
    )
    cols = ros_columns(path)
    assert cols["t"][5] == cols["t"][4]
    _assert_columns(cols, _expected(stamps, q, qd, tau))


def _two_topics(tmp_path):
    arm, gripper = _trajectory(), _trajectory(n=30, joints=("finger",), seed=3)
    path = _write_bag(
        tmp_path / "bag",
        "mcap",
        {
            "/arm/joint_states": (JS, _messages(*arm)),
            "/gripper/joint_states": (JS, _messages(*gripper, joints=("finger",))),
        },
    )
    return path, arm, gripper


def test_several_joint_state_topics_are_listed_and_topic_picks_one(tmp_path):
    path, arm, gripper = _two_topics(tmp_path)
    with pytest.raises(LogError, match="2 sensor_msgs/JointState topics") as err:
        ros_columns(path)
    message = str(err.value)
    assert "/arm/joint_states, /gripper/joint_states" in message and "topic=" in message
    assert "\n" not in message
    _assert_columns(ros_columns(path, topic="/arm/joint_states"), _expected(*arm))
    _assert_columns(
        ros_columns(path, topic="gripper/joint_states"), _expected(*gripper, joints=("finger",))
    )


def test_a_topic_that_is_missing_or_not_joint_state_lists_the_joint_state_topics(tmp_path):
    stamps, q, qd, tau = _trajectory(n=5)
    store = _store("ros2")
    chatter = [(int(s), store.types["std_msgs/msg/String"](data="hi")) for s in stamps]
    path = _write_bag(
        tmp_path / "bag",
        "mcap",
        {
            "/joint_states": (JS, _messages(stamps, q, qd, tau)),
            "/chatter": ("std_msgs/msg/String", chatter),
        },
    )
    with pytest.raises(
        LogError, match=r"no topic '/joints'; its JointState topics are /joint_states"
    ):
        ros_columns(path, topic="/joints")
    with pytest.raises(LogError, match=r"'/chatter' holds std_msgs/msg/String.*are /joint_states"):
        ros_columns(path, topic="/chatter")


@pytest.mark.parametrize("kind", ["mcap", "ros1"])
def test_a_bag_without_joint_states_lists_its_topics(tmp_path, kind):
    store = _store(kind)
    chatter = [(10**9 + k, store.types["std_msgs/msg/String"](data="hi")) for k in range(3)]
    path = _write_bag(tmp_path / "bag", kind, {"/chatter": ("std_msgs/msg/String", chatter)})
    with pytest.raises(
        LogError, match=r"no sensor_msgs/JointState topic.*/chatter \(std_msgs/msg/String\).*topic="
    ):
        ros_columns(path)


def test_current_efforts_give_current_columns(tmp_path):
    stamps, q, qd, current = _trajectory()
    path = _write_bag(
        tmp_path / "bag", "ros1", {"/joint_states": (JS, _messages(stamps, q, qd, current))}
    )
    _assert_columns(
        ros_columns(path, effort="current"), _expected(stamps, q, qd, current, effort="i")
    )
    with pytest.raises(LogError, match="effort='voltage' is not known"):
        ros_columns(path, effort="voltage")


def test_missing_velocities_give_no_velocity_columns(tmp_path):
    stamps, q, qd, tau = _trajectory()
    none = _messages(stamps, q, None, tau)
    some = _messages(stamps, q, qd, tau)
    some[7][1]["qd"] = ()  # one message without velocities
    for name, messages in (("none", none), ("some", some)):
        path = _write_bag(tmp_path / name, "sqlite3", {"/joint_states": (JS, messages)})
        _assert_columns(ros_columns(path), _expected(stamps, q, None, tau))


def test_messages_without_efforts_are_an_error(tmp_path):
    stamps, q, qd, tau = _trajectory(n=5)
    messages = [(r, dict(m, effort=())) for r, m in _messages(stamps, q, qd, tau)]
    path = _write_bag(tmp_path / "bag", "mcap", {"/joint_states": (JS, messages)})
    with pytest.raises(LogError, match="topic /joint_states: the messages have no efforts"):
        ros_columns(path)


def test_a_message_with_too_few_positions_is_an_error(tmp_path):
    stamps, q, qd, tau = _trajectory(n=5)
    messages = _messages(stamps, q, qd, tau)
    messages[3][1]["q"] = q[3, :2]
    path = _write_bag(tmp_path / "bag", "mcap", {"/joint_states": (JS, messages)})
    with pytest.raises(LogError, match=r"message 3 \(counting .* from 0\) has 2 position values"):
        ros_columns(path)


def test_a_message_naming_a_joint_twice_is_an_error(tmp_path):
    stamps, q, qd, tau = _trajectory(n=5)
    messages = _messages(stamps, q, qd, tau)
    messages[2][1]["names"] = ("shoulder", "elbow", "shoulder")
    path = _write_bag(tmp_path / "bag", "mcap", {"/joint_states": (JS, messages)})
    with pytest.raises(LogError, match=r"message 2 .* names joints \['shoulder'\] more than once"):
        ros_columns(path)


@pytest.mark.parametrize("name", ["junk.bag", "junk.mcap", "junk.db3"])
def test_a_file_that_is_not_a_bag_is_a_log_error(tmp_path, name):
    path = tmp_path / name
    path.write_text("t,q_a,tau_a\n0,1,2\n")
    with pytest.raises(LogError, match=f"{name}: cannot read it as a ROS bag") as err:
        ros_columns(path)
    assert "\n" not in str(err.value)


def test_a_truncated_bag_is_a_log_error(tmp_path):
    stamps, q, qd, tau = _trajectory()
    bag = _write_bag(
        tmp_path / "bag", "ros1", {"/joint_states": (JS, _messages(stamps, q, qd, tau))}
    )
    data = bag.read_bytes()
    bag.write_bytes(data[: len(data) // 2])
    with pytest.raises(LogError, match="bag.bag: cannot read it as a ROS bag"):
        ros_columns(bag)


def test_paths_that_are_not_bags(tmp_path):
    (tmp_path / "log.csv").write_text("t\n0\n")
    with pytest.raises(LogError, match=r"log.csv: not a ROS bag; expected a ROS 2 bag folder"):
        ros_columns(tmp_path / "log.csv")
    (tmp_path / "folder").mkdir()
    with pytest.raises(LogError, match="folder: a folder without metadata.yaml is not a ROS 2 bag"):
        ros_columns(tmp_path / "folder")
    with pytest.raises(FileNotFoundError, match="no ROS bag"):
        ros_columns(tmp_path / "missing.bag")


def test_without_rosbags_the_error_says_what_to_install(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)
    with pytest.raises(LogError, match=r'pip install "torchjfa\[ros\]"'):
        ros_columns(tmp_path / "any.bag")


# --------------------------------------------------------------- through read_log and identify
def _bag_and_csv(tmp_path, stamps, joints, q, qd, tau, kind="mcap"):
    """One log written as a bag and, with the time the bag reader gives, as a CSV."""
    from torchjfa.data import JointLog, write_log

    t = (stamps - stamps[0]).astype(np.float64) / 1e9
    csv = tmp_path / "log.csv"
    write_log(JointLog(t=t, q=q, qd=qd, tau=tau, joint_names=joints), csv)
    messages = _messages(stamps, q, qd, tau, joints=joints)
    return _write_bag(tmp_path / "bag", kind, {"/joint_states": (JS, messages)}), csv


@pytest.mark.parametrize("kind", ["sqlite3", "ros1"])
def test_read_log_reads_a_bag_as_the_same_log_as_its_csv(tmp_path, kind):
    from torchjfa.data import read_log

    stamps, q, qd, tau = _trajectory()
    bag, csv = _bag_and_csv(tmp_path, stamps, JOINTS, q, qd, tau, kind)
    a, b = read_log(bag), read_log(csv)
    assert a.joint_names == b.joint_names == JOINTS
    for name in ("t", "q", "qd", "tau"):
        np.testing.assert_array_equal(getattr(a, name).numpy(), getattr(b, name).numpy(), name)
    assert a.info["format"] == "ros"


def test_identify_on_a_bag_gives_the_theta_of_its_csv(tmp_path):
    """The simulated head, a few seconds of it, identified from a bag and from a CSV."""
    import torchjfa
    from torchjfa.sim import generate_log

    sim = generate_log("head", n_samples=2100, seed=4)  # 5 s at 420 Hz
    stamps = START_NS + np.round(sim.t.numpy() * 1e9).astype(np.int64)
    arrays = [getattr(sim, k).numpy() for k in ("q", "qd", "tau")]
    bag, csv = _bag_and_csv(tmp_path, stamps, sim.joint_names, *arrays)
    # the reading is what differs: no projection, no jackknife, no bias refits, no grids
    options = torchjfa.Options(
        jackknife=0, cutoff=20.0, coulomb_velocity=0.05, bias_correction=0, project=False
    )
    theta = [torchjfa.identify("head", log, options).theta.numpy() for log in (bag, csv)]
    assert np.isfinite(theta[0]).all()
    np.testing.assert_allclose(theta[0], theta[1], rtol=1e-12, atol=0)


def test_read_log_turns_a_bags_currents_into_torques_with_the_drive_gains(tmp_path):
    from torchjfa.data import read_log

    stamps, q, qd, current = _trajectory()
    path = _write_bag(
        tmp_path / "bag", "mcap", {"/joint_states": (JS, _messages(stamps, q, qd, current))}
    )
    gains = {"shoulder": 2.0, "elbow": 0.5, "wrist": 4.0}
    log = read_log(path, effort="current", drive_gains=gains)
    want = current * np.array([gains[j] for j in JOINTS])
    np.testing.assert_allclose(log.tau.numpy(), want, rtol=1e-15, atol=0)
