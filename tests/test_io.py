"""sern_jax.infra.io: atomic writes keep the usual file mode; verified npz files; run locks."""

import os
import signal
import stat
import subprocess
import sys
import time
import zipfile

import numpy as np
import pytest

from sern_jax.infra import io


def test_files_get_the_umask_mode_not_0600(tmp_path):
    old = os.umask(0o022)
    try:
        io.save_json(tmp_path / "a.json", {"x": 1})
        io.save_npz(tmp_path / "b.npz", x=[1, 2])
        io.save_text(tmp_path / "c.md", "hi")
        os.umask(0o077)
        io.save_text(tmp_path / "d.md", "private")
    finally:
        os.umask(old)
    for name in ("a.json", "b.npz", "c.md"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o644, name
    assert stat.S_IMODE((tmp_path / "d.md").stat().st_mode) == 0o600
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


# ----------------------------------------------------------------------------- verified npz

def _damage(path, how):
    data = path.read_bytes()
    if how == "truncate":
        path.write_bytes(data[: len(data) // 2])
    elif how == "empty":
        path.write_bytes(b"")
    elif how == "random":
        path.write_bytes(np.random.default_rng(0).bytes(len(data)))
    elif how == "flip":  # one byte inside the compressed data: zip CRC / zlib must catch it
        b = bytearray(data)
        b[len(b) // 3] ^= 0xFF
        path.write_bytes(bytes(b))
    else:
        raise AssertionError(how)


def test_npz_round_trip_hides_the_checksum(tmp_path):
    io.save_npz(tmp_path / "a.npz", x=np.arange(5.0), s=np.asarray("text"), e=np.zeros((0, 3)))
    out = io.load_npz(tmp_path / "a.npz")
    assert sorted(out) == ["e", "s", "x"]
    np.testing.assert_array_equal(out["x"], np.arange(5.0))
    assert str(out["s"]) == "text" and out["e"].shape == (0, 3)
    assert io.verify_npz(tmp_path / "a.npz") is None
    with np.load(tmp_path / "a.npz") as raw:  # the digest is really stored in the file
        assert io.DIGEST_KEY in raw.files
    with pytest.raises(ValueError, match="reserved"):
        io.save_npz(tmp_path / "b.npz", **{io.DIGEST_KEY: 1})


@pytest.mark.parametrize("how", ["truncate", "empty", "random", "flip"])
def test_damaged_npz_is_one_line_naming_the_file(tmp_path, how):
    path = tmp_path / "checkpoint.npz"
    io.save_npz(path, x=np.random.default_rng(1).normal(size=(64, 64)))
    _damage(path, how)
    with pytest.raises(io.DamagedFileError) as info:
        io.load_npz(path, advice="delete it to restart")
    msg = str(info.value)
    assert "\n" not in msg and str(path) in msg and msg.endswith("delete it to restart")
    assert isinstance(info.value, ValueError)  # the command layer's exit 2
    assert io.verify_npz(path) is not None


def test_contents_that_do_not_match_their_digest_are_damaged(tmp_path):
    """A well-formed archive whose arrays were replaced (zip CRCs fine) fails the SHA-256."""
    path = tmp_path / "a.npz"
    io.save_npz(path, x=np.arange(4))
    with np.load(path) as raw:
        digest = raw[io.DIGEST_KEY]
    np.savez(path, x=np.arange(4) + 1, **{io.DIGEST_KEY: digest})
    assert zipfile.ZipFile(path).testzip() is None
    with pytest.raises(io.DamagedFileError, match="SHA-256"):
        io.load_npz(path)


def test_npz_written_before_the_digest_still_loads(tmp_path):
    np.savez_compressed(tmp_path / "old.npz", x=np.arange(3))
    np.testing.assert_array_equal(io.load_npz(tmp_path / "old.npz")["x"], np.arange(3))


def test_missing_npz_is_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError):
        io.load_npz(tmp_path / "nope.npz")
    assert io.load_npz_unit(tmp_path / "nope.npz") is None


@pytest.mark.parametrize("how", ["truncate", "empty", "random"])
def test_damaged_unit_is_set_aside_for_recompute(tmp_path, how):
    path = tmp_path / "shard_00000.npz"
    io.save_npz(path, x=np.arange(1000))
    assert io.npz_unit_done(path, log=None)
    _damage(path, how)
    lines = []
    assert io.load_npz_unit(path, log=lines.append) is None
    assert not path.exists() and (tmp_path / "shard_00000.npz.damaged").exists()
    assert len(lines) == 1 and "damaged" in lines[0] and "recomputing" in lines[0]
    assert not io.npz_unit_done(path, log=None)  # now simply missing


# ----------------------------------------------------------------------------- run locks

_HOLDER = """
import sys, time
from sern_jax.infra import io
with io.run_lock(sys.argv[1], command="holder test"):
    print("locked", flush=True)
    time.sleep(60)
"""


_SECOND = """
import sys
from sern_jax.infra import io
try:
    io.run_lock(sys.argv[1]).__enter__()
except io.RunLockedError as e:
    print(e)
    sys.exit(3)
"""


def _start_holder(run_dir):
    proc = subprocess.Popen([sys.executable, "-c", _HOLDER, str(run_dir)],
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "locked"
    return proc


def test_run_lock_two_processes_and_a_killed_holder(tmp_path):
    run_dir = tmp_path / "run"
    proc = _start_holder(run_dir)
    try:
        with pytest.raises(io.RunLockedError) as info, io.run_lock(run_dir):
            raise AssertionError("took a lock another live process holds")
        msg = str(info.value)
        assert "\n" not in msg and str(run_dir) in msg
        assert f"pid {proc.pid}" in msg and "holder test" in msg
        # a second process (not only this one) is refused too
        other = subprocess.run(
            [sys.executable, "-c", _SECOND, str(run_dir)],
            capture_output=True, text=True, timeout=60, check=False)
        assert other.returncode == 3 and f"pid {proc.pid}" in other.stdout
    finally:
        proc.send_signal(signal.SIGKILL)  # kill -9: no cleanup code runs
        proc.wait()
    # the killed process's lock is gone with it: no stale lock
    with io.run_lock(run_dir, command="next") as d:
        assert d == run_dir
        assert '"command": "next"' in (run_dir / io.LOCK_FILE).read_text()
    assert (run_dir / io.LOCK_FILE).read_text() == ""  # released: names no holder


def test_run_lock_is_released_on_error_and_reentrant_across_runs(tmp_path):
    with pytest.raises(RuntimeError), io.run_lock(tmp_path / "r"):
        raise RuntimeError("run failed")
    start = time.perf_counter()
    with io.run_lock(tmp_path / "r"):
        pass
    assert time.perf_counter() - start < 1.0


def test_run_lock_is_reentrant_within_a_process(tmp_path):
    """A command holding the lock may call a library function that takes it again."""
    with io.run_lock(tmp_path / "r", command="outer"):
        with io.run_lock(tmp_path / "r", command="inner"):
            pass
        # still held by the outer block: another process is refused
        out = subprocess.run([sys.executable, "-c", _SECOND, str(tmp_path / "r")],
                             capture_output=True, text=True, timeout=60, check=False)
        assert out.returncode == 3 and "outer" in out.stdout
    with io.run_lock(tmp_path / "r"):  # released after the outer block
        pass


# ----------------------------------------------------------------------------- run directories

def test_check_run_dir_accepts_new_empty_and_same_fingerprint(tmp_path):
    io.check_run_dir(tmp_path / "absent", "abc")  # a new run
    io.check_run_dir(tmp_path, "abc")  # a directory that saved nothing yet
    io.save_json(tmp_path / "config.json", {"fingerprint": "abc", "x": 1})
    io.check_run_dir(tmp_path, "abc")  # the same experiment resumes
    assert not (tmp_path / "absent").exists()  # reads only


def test_check_run_dir_refuses_in_one_line(tmp_path):
    io.save_json(tmp_path / "config.json", {"fingerprint": "abc"})
    with pytest.raises(ValueError) as e:
        io.check_run_dir(tmp_path, "xyz")
    assert str(e.value) == (f"{tmp_path} holds a different experiment (fingerprint abc != "
                            f"xyz); choose another --out or delete it")
    io.save_json(tmp_path / "config.json", {"other": 1})  # no fingerprint: another program's
    with pytest.raises(ValueError, match="fingerprint None != xyz"):
        io.check_run_dir(tmp_path, "xyz")
    a_file = tmp_path / "f.txt"
    a_file.write_text("x")
    with pytest.raises(ValueError, match=f"^--out {a_file} exists and is not a directory$"):
        io.check_run_dir(a_file, "abc")
    for bad in ("{not json", "[1, 2]", ""):  # unreadable, or JSON but not an object
        (tmp_path / "config.json").write_text(bad)
        with pytest.raises(ValueError) as e:
            io.check_run_dir(tmp_path, "abc", flag="--out-dir")
        assert str(e.value) == (f"{tmp_path / 'config.json'} is unreadable; choose another "
                                f"--out-dir or delete it")
        assert "\n" not in str(e.value)


def test_check_run_dir_names_no_kind_without_its_checkpoint(tmp_path):
    """A directory with another fingerprint's config.json and none of the checkpoint this kind
    of run saves (e.g. a finished `sern regret` run given to `sern grasp learn`) is "a
    different run", not "a different learning run"; with the checkpoint it is named."""
    io.save_json(tmp_path / "config.json", {"fingerprint": "abc"})
    with pytest.raises(ValueError) as e:
        io.check_run_dir(tmp_path, "xyz", what="learning run", checkpoint="checkpoint.npz")
    assert str(e.value) == (f"{tmp_path} holds a different run (fingerprint abc != xyz); "
                            f"choose another --out or delete it")
    io.save_npz(tmp_path / "checkpoint.npz", fingerprint=np.asarray("abc"))
    with pytest.raises(ValueError, match="holds a different learning run"):
        io.check_run_dir(tmp_path, "xyz", what="learning run", checkpoint="checkpoint.npz")
