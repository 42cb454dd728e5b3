"""Outputs nothing clobbers (issue 45): a symlink, a FIFO, a pipe or a device named as an output is
written through, never replaced by a regular file; a folder is refused before the run; a second run
given a file another run is writing is refused before it starts; a file's mode is kept."""

import errno
import json
import os
import signal
import stat
import subprocess
import sys
import time

import pytest

from godobject_drake import cli
from godobject_drake.outputs import OutputError, OutputLock, OutputRefused, check_output, write_atomically

SHORT = ("--duration", "0.05", "--no-progress")


def test_a_symlink_stays_a_symlink_and_its_target_is_rewritten(tmp_path):
    (tmp_path / "runs").mkdir()
    target = tmp_path / "runs" / "m.json"
    target.write_text("old")
    link = tmp_path / "latest.json"
    link.symlink_to(target)
    write_atomically(link, '{"new": 1}')
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert target.read_text() == '{"new": 1}'
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == ["m.json"]  # no temporary left


def test_a_rewritten_file_keeps_its_mode(tmp_path):
    path = tmp_path / "m.json"
    path.write_text("{}")
    path.chmod(0o600)  # private metrics stay private (the rename used to leave 0644)
    write_atomically(path, '{"a": 1}')
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and path.read_text() == '{"a": 1}'
    path.chmod(0o640)
    write_atomically(path, '{"a": 2}')
    assert stat.S_IMODE(path.stat().st_mode) == 0o640


def test_a_fifo_is_written_through_and_stays_a_fifo(tmp_path):
    fifo = tmp_path / "metrics.fifo"
    os.mkfifo(fifo)
    reader = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)  # a reader waiting, as `cat fifo` would
    try:
        assert write_atomically(fifo, '{"a": 1}\n') == 9
        assert stat.S_ISFIFO(os.stat(fifo).st_mode), "the FIFO was replaced by a regular file"
        assert os.read(reader, 100) == b'{"a": 1}\n'
    finally:
        os.close(reader)


def test_a_fifo_nobody_reads_is_refused_at_once_naming_the_fix(tmp_path):
    fifo = tmp_path / "metrics.fifo"
    os.mkfifo(fifo)
    t0 = time.perf_counter()
    with pytest.raises(
        OutputError, match=r"metrics\.fifo .*no process has the FIFO open for reading; start its reader"
    ):
        write_atomically(fifo, "{}")
    assert time.perf_counter() - t0 < 1.0  # not blocked until a reader comes
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


def test_a_pipe_as_bash_gives_it_is_written_through():
    """``--metrics >(jq .)``: bash passes ``/dev/fd/63``, a pipe. The temporary file beside it could
    not be made (there is no folder to make it in), and the run ended on 'Free space on that disk'."""
    read_end, write_end = os.pipe()
    try:
        path = f"/dev/fd/{write_end}"
        check_output(path, "metrics.file")  # accepted before the run
        write_atomically(path, '{"written": "through"}')
        assert os.read(read_end, 100) == b'{"written": "through"}'
    finally:
        os.close(read_end)
        os.close(write_end)


def test_a_device_node_is_written_through_not_replaced(tmp_path):
    """``--metrics /dev/null`` run as root replaced the system's node by a regular file. Here a node
    of our own (root only: mknod), so the old code could not harm the system's."""
    node = tmp_path / "null"
    try:
        os.mknod(node, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    except PermissionError:
        pytest.skip("making a device node needs root")
    write_atomically(node, "discarded")
    assert stat.S_ISCHR(os.stat(node).st_mode) and os.stat(node).st_rdev == os.makedev(1, 3)


def test_a_symlink_loop_is_refused_naming_it(tmp_path):
    (tmp_path / "a.json").symlink_to(tmp_path / "b.json")
    (tmp_path / "b.json").symlink_to(tmp_path / "a.json")
    with pytest.raises(OutputRefused, match=r"metrics\.file: .*a\.json: a symlink loop; point it at a file"):
        check_output(tmp_path / "a.json", "metrics.file")


def test_another_users_symlink_in_a_shared_folder_is_not_followed(tmp_path):
    """The kernel's protected_symlinks rule: in a sticky world-writable folder (/tmp), a link owned
    by someone else is not followed (else a local user could make root's run write anywhere)."""
    if os.geteuid() != 0:
        pytest.skip("making a link owned by another user needs root")
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o1777)
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    link = shared / "m.json"
    link.symlink_to(victim)
    os.lchown(link, 12345, 12345)
    with pytest.raises(OutputRefused, match=r"symlink owned by uid 12345 in a folder anyone can write to"):
        check_output(link, "metrics.file")
    with pytest.raises(OutputError):
        write_atomically(link, "overwritten")
    assert victim.read_text() == "keep me"


@pytest.mark.parametrize("flag, field", [("--metrics", "metrics.file"), ("--record", "recording.file")])
def test_a_folder_as_an_output_is_refused_before_the_run(tmp_path, capsys, flag, field):
    folder = tmp_path / "out"
    folder.mkdir()
    with pytest.raises(SystemExit) as ended:
        cli.main(["run", "lego", *SHORT, flag, str(folder)])
    assert ended.value.code == 2
    err = capsys.readouterr()
    assert f"{field}: {folder} is a folder; give a file name, e.g. {folder}/" in err.err
    assert "sim_time_s" not in err.out  # refused before the run: no metrics table
    assert list(folder.iterdir()) == []


HOLD = """
import sys
from godobject_drake.outputs import OutputLock
lock = OutputLock()
lock.acquire(sys.argv[1], "metrics.file")
print("held", flush=True)
sys.stdin.read()
lock.release()  # as a run does when it ends
"""


def test_a_second_run_on_a_file_another_run_is_writing_is_refused_before_it_starts(tmp_path, capsys):
    """Two runs given one metrics file: the one that finished and said 'metrics written' had its file
    overwritten by the other's partial checkpoint. Now the file is locked for the run (an advisory
    ``flock`` on ``.m.json.lock``, held by another process here) and the second run is refused."""
    path = tmp_path / "m.json"
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(path)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(SystemExit) as ended:
            cli.main(["run", "lego", *SHORT, "--metrics", str(path)])
        assert ended.value.code == 2
        err = capsys.readouterr().err
        assert f"metrics.file: {path} is being written by another run (pid {holder.pid}" in err
        assert "wait for it to finish or give this run another file" in err
        assert not path.exists()
    finally:
        holder.stdin.close()
        holder.wait(timeout=30)
    # the holder gone, its lock file went with it, and the next run takes the file
    assert not (tmp_path / ".m.json.lock").exists()
    assert cli.main(["run", "lego", *SHORT, "--metrics", str(path)]) == 0
    assert json.loads(path.read_text())["partial"] is False
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.json"]


def test_a_lock_left_by_a_killed_run_does_not_block_the_next(tmp_path):
    path = tmp_path / "m.json"
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(path)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    assert holder.stdout.readline().strip() == "held"
    holder.kill()
    holder.wait(timeout=30)
    assert (tmp_path / ".m.json.lock").exists()  # left behind, unlocked
    with OutputLock() as lock:
        lock.acquire(path, "metrics.file")
    assert not (tmp_path / ".m.json.lock").exists()


def test_one_file_for_both_outputs_is_refused(tmp_path, capsys):
    path = tmp_path / "same"
    with pytest.raises(SystemExit) as ended:
        cli.main(["run", "lego", *SHORT, "--metrics", str(path), "--record", str(path)])
    assert ended.value.code == 2
    assert f"recording.file: {path} is already another output of this run" in capsys.readouterr().err


def test_the_errno_of_a_failed_write_is_kept(tmp_path):
    with pytest.raises(OutputError) as raised:
        write_atomically(tmp_path / "no_such_folder" / "m.json", "{}")
    assert raised.value.errno == errno.ENOENT and "Write elsewhere" in str(raised.value)


def test_a_recording_that_cannot_be_written_is_said_on_stderr(tmp_path, capsys):
    """The recording's error went only to a row of the metrics table (stdout). A FIFO nobody reads,
    given as the recording: the run ends, its metrics are printed, and stderr says why the recording
    was not written (exit 1); the FIFO is still a FIFO."""
    fifo = tmp_path / "live.html"
    os.mkfifo(fifo)
    assert cli.main(["run", "lego", *SHORT, "--record", str(fifo)]) == 1
    out, err = capsys.readouterr()
    assert "recording_error" in out and "sim_time_s" in out
    assert f"recording not written: [Errno 6] could not write {fifo}" in err
    assert "no process has the FIFO open for reading; start its reader first" in err
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


class Stopped(Exception):
    """What this test's SIGTERM handler raises (the command line's raises ``Terminated``)."""


def test_a_signal_during_a_write_is_handled_once_the_file_is_whole(tmp_path, monkeypatch):
    """SIGTERM arrives while the data is being synced to disk: the handler raised there, the
    temporary file was left beside the target and the target kept its old text. Now the file is
    written whole first, then the handler runs (its exception raised), and no temporary file is left."""
    path = tmp_path / "m.json"
    path.write_text("old")
    real_fsync = os.fsync

    def fsync_with_a_signal(fd):
        signal.raise_signal(signal.SIGTERM)
        real_fsync(fd)

    def stop(signum, frame):
        raise Stopped()

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        monkeypatch.setattr(os, "fsync", fsync_with_a_signal)
        with pytest.raises(Stopped):
            write_atomically(path, "new")
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert path.read_text() == "new" and sorted(p.name for p in tmp_path.iterdir()) == ["m.json"]
    assert signal.getsignal(signal.SIGTERM) is previous


def test_whatever_ends_a_write_leaves_no_temporary_file(tmp_path, monkeypatch):
    """Not an OSError (a MemoryError here): the temporary file was left; now it is removed and the
    previous file kept."""
    path = tmp_path / "m.json"
    path.write_text("old")

    def fail(fd):
        raise MemoryError()

    monkeypatch.setattr(os, "fsync", fail)
    with pytest.raises(MemoryError):
        write_atomically(path, "new")
    assert path.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["m.json"]


def test_a_signal_the_process_ignores_stays_ignored_while_writing(tmp_path):
    """``nohup`` starts a run with SIGHUP ignored: a hold must not take it (it would note it and end
    the run after the write); the write goes on and SIGHUP stays ignored."""
    from godobject_drake.outputs import SignalsHeld

    previous = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        with SignalsHeld() as held:
            signal.raise_signal(signal.SIGHUP)
            write_atomically(tmp_path / "m.json", "{}")
        assert held.caught == [] and signal.getsignal(signal.SIGHUP) == signal.SIG_IGN
    finally:
        signal.signal(signal.SIGHUP, previous)
