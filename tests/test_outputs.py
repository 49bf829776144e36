"""Results written whole: `torchjfa.io.output_folder` and `atomic_file`, and the commands'
``--out``.

The folder checks below read the manifest and hash the files with `hashlib` here, not with the
library's code: a folder is complete when its ``manifest.json`` lists exactly the files it holds
and every file's SHA-256 is the listed one."""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from torchjfa._util import output_lock
from torchjfa.cli import main
from torchjfa.io import MANIFEST, OutputError, atomic_file, output_folder

FORK = multiprocessing.get_context("fork") if hasattr(os, "fork") else None
needs_fork = pytest.mark.skipif(FORK is None, reason="needs os.fork")


def _complete(folder: Path) -> dict[str, bytes]:
    """The folder's files -> their bytes, after checking that it is one complete result."""
    manifest = json.loads((folder / MANIFEST).read_text())
    held = {p.name for p in folder.iterdir()} - {MANIFEST}
    assert held == set(manifest["files"]), (held, manifest["files"])
    for name, entry in manifest["files"].items():
        data = (folder / name).read_bytes()
        assert hashlib.sha256(data).hexdigest() == entry["sha256"]
        assert len(data) == entry["bytes"]
    return {name: (folder / name).read_bytes() for name in held}


def _staging(folder: Path) -> list[Path]:
    return sorted(folder.parent.glob(f".{folder.name}.partial-*"))


def _write(folder: Path, generation: int, n_files: int = 3, **kwargs) -> None:
    with output_folder(folder, **kwargs) as stage:
        for i in range(n_files):
            (stage / f"f{i}.txt").write_text(f"{generation}\n" * 200)


def test_a_result_replaces_the_earlier_one_whole_and_names_its_inputs(tmp_path):
    out, log = tmp_path / "result", tmp_path / "log.csv"
    log.write_text("t,q_j\n0,1\n")
    _write(out, 1, n_files=4)
    _write(out, 2, n_files=2, inputs=[log], command="torchjfa identify r log.csv")
    files = _complete(out)
    assert set(files) == {"f0.txt", "f1.txt"}  # the earlier run's f2, f3 went with it
    assert all(data.startswith(b"2\n") for data in files.values())
    manifest = json.loads((out / MANIFEST).read_text())
    assert manifest["command"] == "torchjfa identify r log.csv"
    assert manifest["inputs"] == {str(log): hashlib.sha256(log.read_bytes()).hexdigest()}
    assert not _staging(out)
    umask = os.umask(0)
    os.umask(umask)  # the folder gets the mode a plain mkdir gives, not mkdtemp's 0700
    assert stat.S_IMODE(out.stat().st_mode) == 0o777 & ~umask


def test_an_error_inside_leaves_the_earlier_result_as_it_was(tmp_path):
    out = tmp_path / "result"
    _write(out, 1)
    before = _complete(out)
    with pytest.raises(RuntimeError, match="midway"), output_folder(out) as stage:
        (stage / "f0.txt").write_text("half")
        raise RuntimeError("midway")
    assert _complete(out) == before and not _staging(out)


def test_bad_output_paths_are_refused_before_any_work(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputError, match="is a file"), output_folder(tmp_path / "file"):
        pytest.fail("the block ran")
    (tmp_path / "link").symlink_to(tmp_path / "elsewhere", target_is_directory=True)
    with pytest.raises(OutputError, match="symbolic link"), output_folder(tmp_path / "link"):
        pytest.fail("the block ran")
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("the user's")
    with pytest.raises(OutputError, match=r"did not write \(notes\.txt\).*overwrite"):
        _write(mine, 1)
    assert (mine / "notes.txt").read_text() == "the user's"
    _write(mine, 1, overwrite=True)  # asked for: replaced whole
    assert set(_complete(mine)) == {"f0.txt", "f1.txt", "f2.txt"}


def test_a_symbolic_link_inside_the_earlier_result_is_not_followed(tmp_path):
    out, target = tmp_path / "result", tmp_path / "precious.txt"
    target.write_text("keep me")
    _write(out, 1)
    manifest = json.loads((out / MANIFEST).read_text())
    (out / "f0.txt").unlink()
    (out / "f0.txt").symlink_to(target)  # a listed name now points elsewhere
    assert "f0.txt" in manifest["files"]
    _write(out, 2)
    assert target.read_text() == "keep me"
    assert not (out / "f0.txt").is_symlink() and _complete(out)["f0.txt"].startswith(b"2\n")


def _hold(folder: Path, ready, release) -> None:
    with output_folder(folder) as stage:
        (stage / "a.txt").write_text("held")
        ready.set()
        release.wait(30)


@needs_fork
def test_a_second_run_into_the_same_folder_is_refused(tmp_path):
    out = tmp_path / "result"
    ready, release = FORK.Event(), FORK.Event()
    other = FORK.Process(target=_hold, args=(out, ready, release))
    other.start()
    try:
        assert ready.wait(30)
        with pytest.raises(OutputError, match="another run is writing"):
            _write(out, 2)
    finally:
        release.set()
        other.join(30)
    assert other.exitcode == 0
    assert _complete(out) == {"a.txt": b"held"}
    with output_lock(out), output_folder(out) as stage:  # a command holds the lock, then writes
        (stage / "b.txt").write_text("nested")
    assert _complete(out) == {"b.txt": b"nested"}
    with output_folder(out) as stage:  # a folder of the result's own is the result's
        (stage / "figures").mkdir()
    with output_folder(out) as stage:
        (stage / "c.txt").write_text("replaced")
    assert _complete(out) == {"c.txt": b"replaced"}


def _generations(folder: Path, ready) -> None:
    ready.set()
    for generation in range(2, 10_000):
        with output_folder(folder) as stage:
            for i in range(4):
                (stage / f"f{i}.txt").write_text(f"{generation}\n" * 20_000)
                time.sleep(0.002)


@needs_fork
def test_a_run_killed_at_any_moment_leaves_one_complete_result(tmp_path):
    """SIGKILL at 40 moments spread over writes and swaps of a process that writes result
    after result: each time the folder holds one whole result (every file of one generation)."""
    out = tmp_path / "result"
    _write(out, 1, n_files=4)
    seen, left_behind = set(), 0
    for k in range(40):
        ready = FORK.Event()
        writer = FORK.Process(target=_generations, args=(out, ready))
        writer.start()
        assert ready.wait(30)
        time.sleep(0.003 * (k % 13) + 0.001 * k)
        os.kill(writer.pid, signal.SIGKILL)
        writer.join(30)
        left_behind += bool(_staging(out))
        files = _complete(out)
        generations = {data.split(b"\n", 1)[0] for data in files.values()}
        assert len(files) == 4 and len(generations) == 1, generations
        seen |= generations
    assert left_behind > 0  # some kills landed while a result was being written
    assert len(seen) > 1  # and some after a result had replaced the earlier one
    _write(out, 0, n_files=4)  # the next run clears what killed runs left behind
    assert not _staging(out)


def test_atomic_file_keeps_the_earlier_file_on_an_error(tmp_path):
    path = tmp_path / "model.npz"
    path.write_bytes(b"old")
    with pytest.raises(RuntimeError), atomic_file(path) as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError
    assert path.read_bytes() == b"old" and [p.name for p in tmp_path.iterdir()] == ["model.npz"]
    with atomic_file(path) as tmp:
        assert tmp.suffix == ".npz" and tmp.parent == tmp_path
        tmp.write_bytes(b"new")
    assert path.read_bytes() == b"new" and [p.name for p in tmp_path.iterdir()] == ["model.npz"]


# the command line ------------------------------------------------------------------------------


def test_a_bad_out_ends_in_one_line_before_any_work(tmp_path, head_csv, capsys, monkeypatch):
    import torchjfa.identification as identification

    def never(*args, **kwargs):
        raise AssertionError("identify ran before --out was checked")

    monkeypatch.setattr(identification, "identify", never)
    (tmp_path / "file").write_text("x")
    assert main(["identify", "head", str(head_csv), "--out", str(tmp_path / "file")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--out" in err and "is a file" in err
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("the user's")
    assert main(["identify", "head", str(head_csv), "--out", str(mine)]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert main(["simulate", "head", "--out", str(mine)]) == 2  # a folder where a file belongs
    assert "is a folder" in capsys.readouterr().err


def test_evaluate_replaces_its_folder_whole_and_overwrite_replaces_a_foreign_one(
    tmp_path, head_csv, default_run, capsys
):
    model, out = str(default_run.folder / "model.npz"), tmp_path / "ev"
    assert main(["evaluate", model, str(head_csv), "--out", str(out)]) == 0
    first = _complete(out)
    assert "evaluation.json" in first and "torques_0.png" in first
    manifest = json.loads((out / MANIFEST).read_text())
    assert set(manifest["inputs"]) == {os.path.abspath(model), os.path.abspath(head_csv)}
    assert main(["evaluate", model, str(head_csv), "--out", str(out), "--no-plots"]) == 0
    assert set(_complete(out)) == {"evaluation.json"}  # the earlier figure went with its run
    (out / "notes.txt").write_text("the user's")
    assert main(["evaluate", model, str(head_csv), "--out", str(out), "--no-plots"]) == 2
    assert main(["evaluate", model, str(head_csv), "--out", str(out), "--no-plots",
                 "--overwrite"]) == 0  # fmt: skip
    assert set(_complete(out)) == {"evaluation.json"}
    capsys.readouterr()


def _started(args: list[str], folder: Path) -> subprocess.Popen:
    """``torchjfa ARGS`` in a new process, returned once it holds ``folder``'s lock (its
    work has begun: the lock is taken right after the arguments are checked)."""
    lock = folder.parent / f".{folder.name}.lock"
    proc = subprocess.Popen(
        [sys.executable, "-m", "torchjfa", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if lock.exists() and _locked(lock):
            return proc
        time.sleep(0.05)
    proc.kill()
    raise AssertionError(f"the command did not start: {proc.communicate()}")


def _locked(lock: Path) -> bool:
    import fcntl

    with open(lock) as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
        fcntl.flock(fh, fcntl.LOCK_UN)
        return False


@needs_fork
def test_ctrl_c_and_a_kill_leave_the_earlier_result_and_a_second_run_is_refused(
    tmp_path, head_csv, default_run, capsys
):
    import shutil

    out = tmp_path / "rep"
    shutil.copytree(default_run.folder, out)
    before = _complete(out)
    args = ["identify", "head", str(head_csv), "--out", str(out), "--quiet"]
    proc = _started(args, out)
    # meanwhile, a second run into the same folder is refused at once
    assert main(["evaluate", str(out / "model.npz"), str(head_csv), "--out", str(out)]) == 2
    assert "another run is writing" in capsys.readouterr().err
    assert proc.poll() is None  # still at work: the interrupt lands mid-run
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and err.strip().endswith(f"interrupted; {out} is as it was")
    assert _complete(out) == before and not _staging(out)
    proc = _started(args, out)
    time.sleep(0.3)
    assert proc.poll() is None
    proc.kill()
    proc.communicate(timeout=60)
    assert _complete(out) == before


def test_an_interrupt_is_noted_even_where_a_library_turns_it_into_an_error():
    """Ctrl-C inside an import shows up as an ImportError, and a library may wrap it in its own
    error: the command line notes the signal itself, so that it still ends as an interrupt."""
    import os

    from torchjfa.cli._main import _noting_interrupts

    before = signal.getsignal(signal.SIGINT)
    noted: list[int] = []
    with _noting_interrupts(noted):
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1.0)  # the handler runs at the next bytecode
        except KeyboardInterrupt:
            pass
    assert noted == [signal.SIGINT]
    assert signal.getsignal(signal.SIGINT) is before
