"""packlab.policies.model_cache: a model directory is loaded once per process until it changes."""

from __future__ import annotations

import os

from packlab.policies.model_cache import load_once


def test_a_directory_is_loaded_once_until_a_file_changes(tmp_path):
    (tmp_path / "weights.bin").write_bytes(b"a")
    loads = []

    def load():
        loads.append(1)
        return object()

    first = load_once(tmp_path, ("agent", 1), load)
    assert load_once(tmp_path, ("agent", 1), load) is first and len(loads) == 1
    assert load_once(tmp_path, ("agent", 2), load) is not first and len(loads) == 2  # settings
    stat = (tmp_path / "weights.bin").stat()
    (tmp_path / "weights.bin").write_bytes(b"bb")  # retrained: another size and time
    os.utime(tmp_path / "weights.bin", ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))
    assert load_once(tmp_path, ("agent", 1), load) is not first and len(loads) == 3
