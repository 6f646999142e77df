"""The cache protocol (vpr_uncertainty.cache): content keys, fingerprints, atomic writes, notices.

References are independent of the code under test: hashlib on the same bytes, the file system's own view of modes
and file types, and a writer process killed with SIGKILL in the middle of a write.
"""

from __future__ import annotations

import hashlib
import os
import signal
import stat
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from vpr_uncertainty.cache import (
    CacheWarning,
    array_digest,
    atomic_path,
    atomic_write,
    content_key,
    fingerprint,
    read_if_fresh,
    write_text,
)


def test_content_key_is_size_mtime_and_a_hash_of_every_byte(tmp_path):
    file = tmp_path / "a.jpg"
    file.write_bytes(b"\xff\xd8 first image")
    size, mtime, digest = content_key(file).split(":")
    assert int(size) == file.stat().st_size and int(mtime) == file.stat().st_mtime_ns
    assert digest == hashlib.blake2b(file.read_bytes(), digest_size=16).hexdigest()
    before = content_key(file)
    times = (file.stat().st_atime_ns, file.stat().st_mtime_ns)
    file.write_bytes(b"\xff\xd8 other image")  # same size ...
    os.utime(file, ns=times)  # ... and same time: only the hash tells
    assert content_key(file) != before
    assert content_key(file) == content_key(file)


def test_content_key_of_a_large_file_hashes_both_ends(tmp_path, monkeypatch):
    from vpr_uncertainty import cache

    monkeypatch.setattr(cache, "FULL_HASH_BYTES", 16)
    monkeypatch.setattr(cache, "EDGE_BYTES", 4)
    file = tmp_path / "big.npy"
    file.write_bytes(b"HEAD" + b"m" * 100 + b"TAIL")
    expected = hashlib.blake2b(b"HEAD" + b"TAIL", digest_size=16).hexdigest()
    assert content_key(file).endswith(":" + expected)


def test_fingerprint_is_sha256_of_canonical_json_and_ignores_key_order():
    first = fingerprint("retrieval", {"k": 20, "index": "Flat"}, {"db": "x"})
    assert first == fingerprint("retrieval", {"index": "Flat", "k": 20}, {"db": "x"})
    assert len(first) == 64 and int(first, 16) >= 0
    assert first != fingerprint("descriptors", {"k": 20, "index": "Flat"}, {"db": "x"})
    assert first != fingerprint("retrieval", {"k": 20, "index": "Flat"}, {"db": "y"})
    assert fingerprint("s", {"path": Path("/a")}) == fingerprint("s", {"path": "/a"})


def test_array_digest_sees_dtype_shape_and_bytes():
    a = np.arange(6, dtype=np.float32)
    assert array_digest(a) == array_digest(a.copy())
    assert array_digest(a) != array_digest(a.astype(np.float64))
    assert array_digest(a) != array_digest(a.reshape(2, 3))
    assert array_digest(a, None) != array_digest(a)


def test_atomic_write_leaves_the_old_file_when_interrupted(tmp_path):
    target = tmp_path / "results.json"
    target.write_text("old")
    with pytest.raises(KeyboardInterrupt), atomic_write(target) as handle:
        handle.write("half of the ne")
        raise KeyboardInterrupt
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["results.json"]  # no temporary file left


def test_atomic_files_get_the_mode_of_a_plain_write(tmp_path):
    """Regression: mkstemp's 0600 leaked into results that other users of a shared run folder must read."""
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    atomic = write_text(tmp_path / "atomic.txt", "x")
    assert stat.S_IMODE(atomic.stat().st_mode) == stat.S_IMODE(plain.stat().st_mode)
    os.chmod(atomic, 0o640)
    write_text(atomic, "y")  # a rewrite keeps the file's mode
    assert stat.S_IMODE(atomic.stat().st_mode) == 0o640


def test_atomic_write_follows_links_and_writes_pipes_in_place(tmp_path):
    """Regression: a rename over a symbolic link, a device or a pipe replaced it with a plain file."""
    real = tmp_path / "real.json"
    real.write_text("old")
    link = tmp_path / "link.json"
    link.symlink_to(real)
    write_text(link, "new")
    assert link.is_symlink() and real.read_text() == "new"
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    received: list[bytes] = []
    reader = threading.Thread(target=lambda: received.append(fifo.read_bytes()))
    reader.start()
    write_text(fifo, "through the pipe")
    reader.join(timeout=10)
    assert received == [b"through the pipe"] and stat.S_ISFIFO(fifo.stat().st_mode)


_KILLED_WRITER = """
import os, signal, sys
from vpr_uncertainty.cache import atomic_write
with atomic_write(sys.argv[1], "wb") as handle:
    handle.write(b"n" * 1_000_000)
    handle.flush()
    os.kill(os.getpid(), signal.SIGKILL)
"""


def test_sigkill_mid_write_leaves_the_previous_file_whole(tmp_path):
    target = tmp_path / "retrieval.npz"
    target.write_bytes(b"o" * 1000)
    environment = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    process = subprocess.run([sys.executable, "-c", _KILLED_WRITER, str(target)], env=environment, check=False)
    assert process.returncode == -signal.SIGKILL
    assert target.read_bytes() == b"o" * 1000  # the previous file, whole; the partial write is a hidden temp file


def test_atomic_path_keeps_the_suffix_for_writers_that_infer_the_format(tmp_path):
    with atomic_path(tmp_path / "figure.png") as temporary:
        assert temporary.suffix == ".png" and temporary.parent == tmp_path
        temporary.write_bytes(b"png")
    assert (tmp_path / "figure.png").read_bytes() == b"png"


def test_read_if_fresh_reports_a_truncated_cache_in_one_line(tmp_path):
    path = tmp_path / "a.npz"
    path.write_bytes(b"PK\x03\x04 cut")

    def read(file):
        with np.load(file) as archive:
            return dict(archive)

    with pytest.warns(CacheWarning) as caught:
        assert read_if_fresh(path, "f", read, lambda arrays: "f", errors=(ValueError, OSError, Exception)) is None
    (notice,) = [str(w.message) for w in caught if issubclass(w.category, CacheWarning)]
    assert "\n" not in notice and "truncated" in notice and str(path) in notice
    np.savez(path, fingerprint=np.array("f"))
    assert read_if_fresh(path, "f", read, lambda arrays: str(arrays["fingerprint"])) is not None
    assert read_if_fresh(path, "g", read, lambda arrays: str(arrays["fingerprint"])) is None
    with pytest.warns(CacheWarning, match="earlier version"):
        assert read_if_fresh(path, "f", read, lambda arrays: None) is None
